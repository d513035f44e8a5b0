/* test_bodies.c — the bodies module (server/sim/bodies*.c) against theory,
 * measured from the simulation: Archimedes, the heave period with its
 * added mass, following a long swell, ship against dinghy in waves, top
 * speed and turning circle, determinism and save/restore, and the API's
 * refusals. Literature and figures: docs/simulation.md, "Bodies".
 *
 * One line per check ("ok" / "FAIL"), then "N passed, M failed"; exit 1 on
 * any failure. OCEAN_TEST_QUICK=1 runs shorter simulations (valgrind).
 * OCEAN_TEST_ONLY=test_name runs one group. Build and run: make test-bodies. */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bodies.h"

#include "common/check.h"

#define RHO BODY_WATER_DENSITY
#define G   BODY_GRAVITY
#define PI  3.14159265358979323846
#define DEG (180 / PI)

static int quick;
static const char *only;

static double seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* ---- helpers ------------------------------------------------------------- */

static struct body_state state_of(const struct body_world *w, uint32_t id)
{
    struct body_state s = {0};
    for (int i = 0; i < body_world_count(w); i++) {
        body_world_get(w, i, &s);
        if (s.id == id)
            return s;
    }
    memset(&s, 0, sizeof s);
    return s;
}

/* World y of a body-frame point of s. */
static double world_y(const struct body_state *s, double bx, double by, double bz)
{
    double w = s->quat[0], x = s->quat[1], y = s->quat[2], z = s->quat[3];
    return s->pos[1] + 2 * (x * y + w * z) * bx + (1 - 2 * (x * x + z * z)) * by + 2 * (y * z - w * x) * bz;
}

/* The keel's depth below still water (positive down). */
static double keel_depth(const struct body_state *s, double kg) { return -world_y(s, 0, -kg, 0); }

static double kind_kg(const struct body_kind *k)
{
    static const double def[] = {[BODY_HULL_CYLINDER] = 0.25, [BODY_HULL_SPHERE] = 0.4, [BODY_HULL_BOX] = 0.5,
                                 [BODY_HULL_SHIP] = 0.45};
    return k->kg > 0 ? k->kg : def[k->hull] * k->height;
}

static void step_for(struct body_world *w, const struct body_sea *sea, double *t, double secs, double dt)
{
    int n = (int)(secs / dt + 0.5);
    for (int i = 0; i < n; i++) {
        *t += dt;
        body_world_step(w, sea, *t, dt, NULL, NULL, 0);
    }
}

/* ---- seas ------------------------------------------------------------------ */

/* A long-crested deep-water swell eta = a cos(k (x cos d + z sin d) - w t),
 * w^2 = g k, summed over up to two components. */
struct swell {
    int n;
    double a[2], k[2], w[2], dir[2];
    long points; /* sampled, for the record */
};
static int swell_sample(void *ctx, double t, int n, const double (*xz)[2], double *height, double *dhdt)
{
    struct swell *s = ctx;
    for (int i = 0; i < n; i++) {
        height[i] = dhdt[i] = 0;
        for (int c = 0; c < s->n; c++) {
            double ph = s->k[c] * (xz[i][0] * cos(s->dir[c]) + xz[i][1] * sin(s->dir[c])) - s->w[c] * t;
            height[i] += s->a[c] * cos(ph);
            dhdt[i] += s->a[c] * s->w[c] * sin(ph);
        }
    }
    s->points += n;
    return 0;
}
static struct swell swell_one(double amp, double wavelength)
{
    struct swell s = {0};
    s.n = 1;
    s.a[0] = amp;
    s.k[0] = 2 * PI / wavelength;
    s.w[0] = sqrt(G * s.k[0]);
    return s;
}

/* A sea that fails, and one that gives NaN: both must be still water. */
static int failing_sample(void *ctx, double t, int n, const double (*xz)[2], double *height, double *dhdt)
{
    for (int i = 0; i < n; i++)
        height[i] = dhdt[i] = 1e3; /* garbage the step must not read */
    return -1;
}
static int nan_sample(void *ctx, double t, int n, const double (*xz)[2], double *height, double *dhdt)
{
    for (int i = 0; i < n; i++)
        height[i] = dhdt[i] = NAN;
    return 0;
}

/* ---- the table --------------------------------------------------------------- */

static void test_table(void)
{
    check_section = "table";
    const struct body_kind *k = body_kinds();
    CHECK(k && BODY_KIND_COUNT == 5, "five kinds");
    const char *names[] = {"spar", "ball", "dinghy", "boat", "ship"};
    for (int i = 0; i < BODY_KIND_COUNT; i++) {
        CHECK(strcmp(k[i].name, names[i]) == 0 && body_kind_find(names[i]) == &k[i], "kind %d is %s", i, names[i]);
        CHECK(k[i].powered == (i >= 2), "%s powered: %d", k[i].name, k[i].powered);
        if (k[i].powered)
            CHECK(k[i].top_speed > 0 && k[i].turning_diameter > 0, "%s: top speed %.1f m/s, turning diameter %.0f m",
                  k[i].name, k[i].top_speed, k[i].turning_diameter);
    }
    CHECK(body_kind_find("submarine") == NULL && body_kind_find(NULL) == NULL, "unknown names find nothing");
    CHECK(k[2].length > 2.5 && k[2].length < 3.5 && fabs(k[3].length - 12) < 1 && fabs(k[4].length - 60) < 1,
          "sizes: dinghy %.1f m, boat %.1f m, ship %.1f m", k[2].length, k[3].length, k[4].length);
    double dpl = k[4].turning_diameter / k[4].length;
    CHECK(dpl >= 3 && dpl <= 5, "the ship turns in %.1f lengths (3-5)", dpl);

    /* The documented draft is what the physics gives: launched, and after
     * 20 s in still water. */
    struct body_world *w = body_world_new(8);
    for (int i = 0; i < BODY_KIND_COUNT; i++) {
        uint32_t id;
        body_launch(w, &k[i], 40.0 * i, 0, 0, &id);
        struct body_state s0 = state_of(w, id);
        double d0 = keel_depth(&s0, kind_kg(&k[i]));
        CHECK(fabs(d0 - k[i].draft) < 5e-4 * k[i].draft + 1e-4, "%s launched at draft %.4f m, table %.4f m", k[i].name,
              d0, k[i].draft);
    }
    double t = 0;
    step_for(w, NULL, &t, 20, 1.0 / 30);
    for (int i = 0; i < BODY_KIND_COUNT; i++) {
        struct body_state s;
        body_world_get(w, i, &s);
        double d = keel_depth(&s, kind_kg(&k[i]));
        CHECK(fabs(d - k[i].draft) < 5e-3 * k[i].draft, "%s after 20 s still water: draft %.4f m (table %.4f m)",
              k[i].name, d, k[i].draft);
        double hd, pitch, roll;
        body_attitude(&s, &hd, &pitch, &roll);
        CHECK(fabs(pitch) < 0.01 && fabs(roll) < 0.01, "%s stays level: pitch %.2g, roll %.2g deg", k[i].name, pitch,
              roll);
    }
    body_world_free(w);
}

/* ---- Archimedes --------------------------------------------------------------- */

static void test_archimedes(void)
{
    check_section = "archimedes";
    /* A flat box (4 x 4 x 1 m) of half the water's density: Archimedes puts
     * its keel 0.5 m deep. Dropped from 0.2 m deep and from 0.9 m deep, it
     * settles there. */
    struct body_kind box = {.name = "box", .hull = BODY_HULL_BOX, .length = 4, .beam = 4, .height = 1};
    box.mass = 0.5 * RHO * 16;
    double starts[2] = {0.2, 0.9};
    for (int r = 0; r < 2; r++) {
        struct body_world *w = body_world_new(1);
        struct body_state s = {.id = 7, .kind = &box, .quat = {1, 0, 0, 0}};
        s.pos[1] = 0.5 - starts[r]; /* centre of mass 0.5 m above the keel */
        CHECK(body_world_restore(w, &s) == BODY_OK, "restore the box with its keel %.1f m deep", starts[r]);
        double t = 0;
        step_for(w, NULL, &t, 40, 1.0 / 30);
        struct body_state e = state_of(w, 7);
        double d = keel_depth(&e, 0.5);
        CHECK(fabs(d - 0.5) < 0.005, "density 0.5 from %.1f m deep settles at draft %.4f m = %.2f %% of its height "
              "(Archimedes 50 %%, within 1 %%)", starts[r], d, 100 * d);
        body_world_free(w);
    }

    /* Denser than water (1.05): it sinks and is reported; 0.95 floats on. */
    double ratios[2] = {1.05, 0.95};
    for (int r = 0; r < 2; r++) {
        struct body_kind b = box;
        b.mass = ratios[r] * RHO * 16;
        struct body_world *w = body_world_new(2);
        uint32_t id = 0;
        CHECK(body_launch(w, &b, 0, 0, 0, &id) == BODY_OK, "launch a box of density %.2f", ratios[r]);
        double t = 0, gone_at = -1;
        uint32_t gid = 0;
        enum body_gone why = 0;
        for (int i = 0; i < 30 * 120 && gone_at < 0; i++) {
            t += 1.0 / 30;
            if (body_world_step(w, NULL, t, 1.0 / 30, &gid, &why, 1) == 1)
                gone_at = t;
        }
        if (ratios[r] > 1)
            CHECK(gone_at > 0 && gid == id && why == BODY_GONE_SUNK && body_world_count(w) == 0,
                  "density %.2f sinks: reported gone (sunk) after %.1f s, world empty", ratios[r], gone_at);
        else
            CHECK(gone_at < 0 && body_world_count(w) == 1,
                  "density %.2f still afloat after 120 s", ratios[r]);
        body_world_free(w);
    }
}

/* ---- heave ----------------------------------------------------------------------- */

/* Released 0.5 m above its rest in still water: the heave period from the
 * upward zero crossings, against T = 2 pi sqrt((m + a33) / (rho g A_wp))
 * with a33 = 4/3 rho r^3 (half a disc's 8/3 rho r^3: DNV-RP-H103 Table A-2,
 * Newman 1977 ch. 4). */
static void heave_case(const struct body_kind *k)
{
    struct body_world *w = body_world_new(1);
    uint32_t id;
    body_launch(w, k, 0, 0, 0, &id);
    struct body_state s = state_of(w, id);
    double rest = s.pos[1];
    body_remove(w, id);
    s.pos[1] += 0.5;
    s.id = 1;
    body_world_restore(w, &s);
    double r = 0.5 * k->beam, t = 0, prev = 0.5, cross[16];
    int nc = 0;
    double peak[16] = {0};
    int np = 0;
    double top = 0;
    for (int i = 0; i < 120 * 60 && nc < 16; i++) {
        t += BODY_SUBSTEP_S;
        body_world_step(w, NULL, t, BODY_SUBSTEP_S, NULL, NULL, 0);
        struct body_state e = state_of(w, 1);
        double y = e.pos[1] - rest;
        if (prev < 0 && y >= 0)
            cross[nc++] = t - BODY_SUBSTEP_S * y / (y - prev);
        if (y > 0)
            top = fmax(top, y);
        if (prev >= 0 && y < 0 && top > 0 && np < 16) {
            peak[np++] = top;
            top = 0;
        }
        prev = y;
    }
    int cycles = nc - 1 < 4 ? nc - 1 : 4;
    double period = cycles > 0 ? (cross[cycles] - cross[0]) / cycles : 0;
    double a33 = 4.0 / 3.0 * RHO * r * r * r, awp = PI * r * r;
    double theory = 2 * PI * sqrt((k->mass + a33) / (RHO * G * awp));
    double dry = 2 * PI * sqrt(k->mass / (RHO * G * awp));
    CHECK(cycles == 4 && fabs(period / theory - 1) < 0.05,
          "%s: heave period %.4f s over %d cycles, theory with a33 = %.1f kg: %.4f s (%+.2f %%; without a33 "
          "%.4f s, %+.2f %%)", k->name, period, cycles, a33, theory, 100 * (period / theory - 1), dry,
          100 * (period / dry - 1));
    CHECK(np >= 4 && peak[3] < 0.7 * peak[0] && peak[0] < 0.5,
          "%s: the oscillation decays: crests %.3f, %.3f, %.3f, %.3f m", k->name, peak[0], peak[1], peak[2], peak[3]);
    body_world_free(w);
}

static void test_heave(void)
{
    check_section = "heave";
    heave_case(body_kind_find("spar"));
    /* A squat can buoy (2 m across, 2 m high, 1 m draft): its added mass is
     * 42 % of its mass, so the period tells a33 apart. */
    struct body_kind can = {.name = "can", .hull = BODY_HULL_CYLINDER, .length = 2, .beam = 2, .height = 2,
                            .mass = RHO * PI * 1.0, .kg = 0.5};
    heave_case(&can);
}

/* ---- waves -------------------------------------------------------------------------- */

struct motion {
    double heave, pitch, roll; /* amplitudes sqrt(2) * standard deviation: m, deg, deg */
    double surface;            /* the same of the surface at the body's centre */
    double ratio, lag;         /* heave against the surface at its centre: gain, phase lag (rad) */
};

/* One body of kind k at the origin, heading hd, on sea sw for `secs`,
 * measured over the last `fit_secs`. A body may drift with the waves, so
 * everything is measured against the surface where its centre is (gain
 * and phase: a regression of the heave on that surface's height and its
 * quadrature, dhdt / w, which for one component has the same amplitude). */
static struct motion ride(const struct body_kind *k, double hd, struct swell *sw, double secs, double fit_secs)
{
    struct body_world *w = body_world_new(1);
    uint32_t id;
    body_launch(w, k, 0, 0, hd, &id);
    struct body_sea sea = {swell_sample, sw};
    double t = 0, dt = 1.0 / 30, sum[4] = {0}, sq[4] = {0}, see = 0, seq = 0, sqq = 0, sye = 0, syq = 0;
    int n = (int)(secs / dt + 0.5), m = 0;
    double *y = malloc((size_t)n * sizeof *y), *e = malloc((size_t)n * sizeof *e), *q = malloc((size_t)n * sizeof *q);
    for (int i = 0; i < n; i++) {
        t += dt;
        body_world_step(w, &sea, t, dt, NULL, NULL, 0);
        if (t <= secs - fit_secs)
            continue;
        struct body_state s = state_of(w, id);
        double h, p, r, xz[1][2] = {{s.pos[0], s.pos[2]}}, eta, deta;
        body_attitude(&s, &h, &p, &r);
        swell_sample(sw, t, 1, (const double (*)[2])xz, &eta, &deta);
        double v[4] = {s.pos[1], p, r, eta};
        for (int c = 0; c < 4; c++)
            sum[c] += v[c], sq[c] += v[c] * v[c];
        y[m] = s.pos[1], e[m] = eta, q[m] = deta / sw->w[0];
        m++;
    }
    double amp[4];
    for (int c = 0; c < 4; c++)
        amp[c] = sqrt(2 * fmax(0, sq[c] / m - (sum[c] / m) * (sum[c] / m)));
    double ym = sum[0] / m;
    for (int i = 0; i < m; i++) {
        double yy = y[i] - ym;
        see += e[i] * e[i], seq += e[i] * q[i], sqq += q[i] * q[i], sye += yy * e[i], syq += yy * q[i];
    }
    double det = see * sqq - seq * seq, al = (sye * sqq - syq * seq) / det, be = (syq * see - sye * seq) / det;
    struct motion mo = {amp[0], amp[1], amp[2], amp[3], sqrt(al * al + be * be), atan2(-be, al)};
    free(y), free(e), free(q);
    body_world_free(w);
    return mo;
}

static void test_waves(void)
{
    check_section = "waves";
    const struct body_kind *ball = body_kind_find("ball"), *dinghy = body_kind_find("dinghy"),
                           *ship = body_kind_find("ship");
    /* A 1 m ball on a 100 m swell of 0.5 m amplitude (period 8.0 s). */
    struct swell sw = swell_one(0.5, 100);
    double secs = quick ? 32 : 64;
    struct motion b = ride(ball, 0, &sw, secs, quick ? 16 : 24);
    CHECK(fabs(b.ratio - 1) < 0.05 && fabs(b.heave / b.surface - 1) < 0.05,
          "ball on a 100 m swell: heave %.4f x the surface at its centre (amplitudes %.4f m / %.4f m)", b.ratio,
          b.heave, b.surface);
    CHECK(fabs(b.lag * DEG) < 10, "ball: heave lags the surface at its centre by %+.2f deg", b.lag * DEG);

    /* A 40 m swell (period 5.1 s), 0.5 m: head seas (bow east, into the
     * waves travelling +x, i.e. west) and beam seas (bow north). The ship
     * is 1.5 wavelengths long, the dinghy 0.075. */
    struct swell s40 = swell_one(0.5, 40);
    double ride_s = quick ? 45 : 90, fit_s = quick ? 20 : 50;
    struct motion dh = ride(dinghy, 90, &s40, ride_s, fit_s);
    struct motion sh = ride(ship, 90, &s40, ride_s, fit_s);
    struct motion sb = ride(ship, 0, &s40, ride_s, fit_s);
    double slope = s40.k[0] * 0.5 * DEG;
    CHECK(sh.heave < 0.6 * dh.heave, "head seas, 40 m swell: ship heaves %.3f m, dinghy %.3f m (surface %.3f m)",
          sh.heave, dh.heave, dh.surface);
    CHECK(sh.pitch < 0.6 * dh.pitch, "head seas: ship pitches %.2f deg, dinghy %.2f deg (wave slope %.2f deg)",
          sh.pitch, dh.pitch, slope);
    CHECK(sb.roll > 5 * sh.roll + 0.5, "ship rolls %.2f deg in beam seas, %.3f deg in head seas", sb.roll, sh.roll);
    printf("     (ship in beam seas: heave %.3f m, pitch %.3f deg)\n", sb.heave, sb.pitch);
}

/* Rough seas: every kind, powered ones at full ahead and half rudder, in
 * two crossing components for two minutes. Nothing blows up, no floating
 * body is lost; in a rough but not breaking sea (steepness H/L 1/20 and
 * 1/25) they stay on the surface and the craft upright. In the steep one
 * (1/12 and 1/9, near breaking) small craft at full speed leave the water
 * and may capsize: there the figures are printed, not judged. */
static void storm_case(const char *what, const double amp[2], const double len[2], bool upright)
{
    struct swell sw = {0};
    sw.n = 2;
    double dir[2] = {0, 0.9};
    for (int c = 0; c < 2; c++)
        sw.a[c] = amp[c], sw.k[c] = 2 * PI / len[c], sw.w[c] = sqrt(G * sw.k[c]), sw.dir[c] = dir[c];
    struct body_sea sea = {swell_sample, &sw};
    struct body_world *w = body_world_new(8);
    for (int i = 0; i < BODY_KIND_COUNT; i++) {
        uint32_t id;
        body_launch_on(w, &body_kinds()[i], 100.0 * i, 0, 30.0 * i, &sea, 0, &id);
        struct body_control c = {1, 0.5};
        body_steer(w, id, &c);
    }
    double t = 0, worst_roll[BODY_KIND_COUNT] = {0}, worst_off[BODY_KIND_COUNT] = {0}, start_off = 0;
    struct body_state s0;
    body_world_get(w, 1, &s0);
    double xz0[1][2] = {{s0.pos[0], s0.pos[2]}}, eta0, deta0;
    swell_sample(&sw, 0, 1, (const double (*)[2])xz0, &eta0, &deta0);
    double ball_rest = kind_kg(&body_kinds()[1]) - body_kinds()[1].draft; /* centre of mass above the water */
    CHECK(fabs(s0.pos[1] - eta0 - ball_rest) < 0.05 && fabs(s0.vel[1] - deta0) < 0.05,
          "%s: launched on the sea, the ball at %.3f m over a surface at %.3f m, rising %.3f m/s with it (%.3f)",
          what, s0.pos[1], eta0, s0.vel[1], deta0);
    int finite = 1, lost = 0;
    for (int i = 0; i < (quick ? 30 * 15 : 30 * 120); i++) {
        t += 1.0 / 30;
        lost += body_world_step(w, &sea, t, 1.0 / 30, NULL, NULL, 0);
        for (int b = 0; b < body_world_count(w); b++) {
            struct body_state s;
            body_world_get(w, b, &s);
            double h, p, r, xz[1][2] = {{s.pos[0], s.pos[2]}}, eta, deta;
            body_attitude(&s, &h, &p, &r);
            for (int k = 0; k < 3; k++)
                finite &= isfinite(s.pos[k]) && isfinite(s.vel[k]) && isfinite(s.omega[k]);
            swell_sample(&sw, t, 1, (const double (*)[2])xz, &eta, &deta);
            if (i < 30 && b == 1)
                start_off = fmax(start_off, fabs(s.pos[1] - eta - ball_rest));
            worst_roll[b] = fmax(worst_roll[b], fabs(r));
            worst_off[b] = fmax(worst_off[b], fabs(s.pos[1] - eta));
        }
    }
    CHECK(start_off < 0.3, "%s: the ball's first second within %.3f m of its rest on the surface", what, start_off);
    CHECK(finite && lost == 0 && body_world_count(w) == BODY_KIND_COUNT, "%s: %d bodies, all finite, none lost", what,
          body_world_count(w));
    for (int b = 0; b < body_world_count(w); b++) {
        const struct body_kind *k = &body_kinds()[b];
        CHECK(!upright || (worst_off[b] < k->height + 2 && (!k->powered || worst_roll[b] < 45)),
              "%s: %s's centre at most %.2f m off the surface, roll at most %.1f deg", what, k->name, worst_off[b],
              worst_roll[b]);
    }
    body_world_free(w);
}

static void test_storm(void)
{
    check_section = "storm";
    storm_case("rough (1.5 m at 60 m, 0.4 m at 20 m)", (double[2]){1.5, 0.4}, (double[2]){60, 20}, true);
    if (!quick)
        storm_case("steep (2 m at 50 m, 0.8 m at 15 m)", (double[2]){2.0, 0.8}, (double[2]){50, 15}, false);
}

/* ---- powered -------------------------------------------------------------------------- */

static double heading_of(const struct body_state *s)
{
    double h;
    body_attitude(s, &h, NULL, NULL);
    return h;
}

static void test_powered(void)
{
    check_section = "powered";
    const struct body_kind *k = body_kinds();
    for (int i = 2; i < BODY_KIND_COUNT; i++) {
        if (quick && i != 2)
            continue;
        struct body_world *w = body_world_new(1);
        uint32_t id;
        body_launch(w, &k[i], 0, 0, 0, &id);
        struct body_control full = {1, 0};
        body_steer(w, id, &full);
        /* Full ahead for 7 of the thrust's time constants, 16 sqrt(L/g). */
        double t = 0, tau = 16 * sqrt(k[i].length / G);
        step_for(w, NULL, &t, 7 * tau, 1.0 / 30);
        struct body_state s = state_of(w, id);
        double u = hypot(s.vel[0], s.vel[2]);
        CHECK(fabs(u / k[i].top_speed - 1) < 0.05 && s.vel[2] > 0,
              "%s: full ahead from rest for %.0f s reaches %.3f m/s, table %.1f m/s (%+.2f %%)", k[i].name, 7 * tau,
              u, k[i].top_speed, 100 * (u / k[i].top_speed - 1));
        /* Full rudder to starboard: settle for a turn, then one full turn
         * measured (least squares circle of the centre of mass's track). */
        struct body_control turn = {1, 1};
        body_steer(w, id, &turn);
        double h0 = heading_of(&s);
        step_for(w, NULL, &t, 1.0, 1.0 / 30);
        struct body_state s1 = state_of(w, id);
        double dh = remainder(heading_of(&s1) - h0, 360);
        CHECK(dh > 0, "%s: rudder +1 turns to starboard (heading %+.2f deg in 1 s)", k[i].name, dh);
        double circ = PI * k[i].turning_diameter / k[i].top_speed;
        step_for(w, NULL, &t, 1.5 * circ, 1.0 / 30);
        /* One revolution: sum x, z, x^2 ... for the algebraic (Kasa) fit. */
        double sx = 0, sz = 0, sxx = 0, szz = 0, sxz = 0, sxr = 0, szr = 0, sr = 0, turned = 0, last = heading_of(&s1);
        int n = 0;
        double speed = 0;
        while (turned < 360 && n < 1000000) {
            t += 1.0 / 30;
            body_world_step(w, NULL, t, 1.0 / 30, NULL, NULL, 0);
            struct body_state e = state_of(w, id);
            double x = e.pos[0], z = e.pos[2], rr = x * x + z * z, hd = heading_of(&e);
            turned += remainder(hd - last, 360);
            last = hd;
            sx += x, sz += z, sxx += x * x, szz += z * z, sxz += x * z, sxr += x * rr, szr += z * rr, sr += rr;
            speed += hypot(e.vel[0], e.vel[2]);
            n++;
        }
        /* Kasa: minimise sum (x^2 + z^2 + D x + E z + F)^2. */
        double a[3][4] = {{sxx, sxz, sx, -sxr}, {sxz, szz, sz, -szr}, {sx, sz, n, -sr}};
        for (int c = 0; c < 3; c++)
            for (int r = c + 1; r < 3; r++) {
                double m = a[r][c] / a[c][c];
                for (int j = c; j < 4; j++)
                    a[r][j] -= m * a[c][j];
            }
        double sol[3];
        for (int r = 2; r >= 0; r--) {
            double v = a[r][3];
            for (int j = r + 1; j < 3; j++)
                v -= a[r][j] * sol[j];
            sol[r] = v / a[r][r];
        }
        double diam = 2 * sqrt(sol[0] * sol[0] / 4 + sol[1] * sol[1] / 4 - sol[2]);
        CHECK(fabs(diam / k[i].turning_diameter - 1) < 0.10,
              "%s: steady turning circle at full rudder %.2f m, table %.0f m (%+.2f %%); speed in the turn %.2f m/s, "
              "one turn in %.1f s", k[i].name, diam, k[i].turning_diameter, 100 * (diam / k[i].turning_diameter - 1),
              speed / n, n / 30.0);
        /* Astern: half thrust, slower than ahead. */
        struct body_control astern = {-1, 0};
        body_steer(w, id, &astern);
        step_for(w, NULL, &t, 7 * tau, 1.0 / 30);
        struct body_state ea = state_of(w, id);
        double ub = hypot(ea.vel[0], ea.vel[2]);
        CHECK(ub < 0.8 * k[i].top_speed && ub > 0.5 * k[i].top_speed, "%s: full astern %.2f m/s", k[i].name, ub);
        body_world_free(w);
    }
}

/* ---- determinism --------------------------------------------------------------------------- */

/* A scene: eight bodies of every kind on an oblique two-component sea,
 * steered on a schedule, stepped at 30 Hz with an irregular tick now and
 * then (as a loaded daemon would). */
static void scene_launch(struct body_world *w)
{
    const struct body_kind *k = body_kinds();
    for (int i = 0; i < 8; i++) {
        uint32_t id;
        body_launch(w, &k[i % BODY_KIND_COUNT], -100 + 37.0 * i, 20.0 * (i % 3), 45.0 * i, &id);
    }
}
static double scene_dt(int tick) { return tick % 17 == 5 ? 2.0 / 30 : 1.0 / 30; }
static void scene_steer(struct body_world *w, int tick)
{
    if (tick % 45 != 0)
        return;
    for (int i = 0; i < body_world_count(w); i++) {
        struct body_state s;
        body_world_get(w, i, &s);
        struct body_control c = {((tick / 45 + i) % 5 - 2) / 2.0, ((tick / 45 + 2 * i) % 3 - 1) * 0.8};
        body_steer(w, s.id, &c);
    }
}
static struct swell scene_sea(void)
{
    struct swell s = swell_one(0.8, 70);
    s.n = 2;
    s.a[1] = 0.4, s.k[1] = 2 * PI / 25, s.w[1] = sqrt(G * s.k[1]), s.dir[1] = 0.7;
    return s;
}
static int states_equal(const struct body_world *a, const struct body_world *b)
{
    if (body_world_count(a) != body_world_count(b) || body_world_next_id(a) != body_world_next_id(b))
        return 0;
    for (int i = 0; i < body_world_count(a); i++) {
        struct body_state x, y;
        memset(&x, 0, sizeof x);
        memset(&y, 0, sizeof y);
        body_world_get(a, i, &x);
        body_world_get(b, i, &y);
        if (memcmp(&x, &y, sizeof x) != 0)
            return 0;
    }
    return 1;
}

/* One part of a step on a thread of its own (body_world_step_part). */
struct part_job {
    struct body_world *w;
    const struct body_sea *sea;
    double t, dt;
    int i0, i1;
};
static void *part_run(void *arg)
{
    struct part_job *j = arg;
    body_world_step_part(j->w, j->sea, j->t, j->dt, j->i0, j->i1);
    return NULL;
}
/* A step as the daemon spreads it: the first half of the bodies on another
 * thread while this one steps the second half, each with its own sampler
 * (swell_sample counts its points), then the end. Returns 0 when the thread
 * could not start. */
static int step_in_parts(struct body_world *w, struct swell *s0, struct swell *s1, double t, double dt)
{
    struct body_sea sea0 = {swell_sample, s0}, sea1 = {swell_sample, s1};
    int half = body_world_count(w) / 2;
    struct part_job j = {w, &sea0, t, dt, 0, half};
    pthread_t th;
    if (pthread_create(&th, NULL, part_run, &j) != 0)
        return 0;
    body_world_step_part(w, &sea1, t, dt, half, body_world_count(w));
    pthread_join(th, NULL);
    body_world_step_end(w, NULL, NULL, 0);
    return 1;
}

static void test_determinism(void)
{
    check_section = "determinism";
    int ticks = quick ? 120 : 600, save_at = ticks / 2;
    struct swell sa = scene_sea(), sb = scene_sea(), sc = scene_sea();
    struct body_sea seaa = {swell_sample, &sa}, seab = {swell_sample, &sb}, seac = {swell_sample, &sc};
    struct swell se0 = scene_sea(), se1 = scene_sea();
    struct body_world *a = body_world_new(16), *b = body_world_new(16), *c = NULL, *e = body_world_new(16);
    scene_launch(a);
    scene_launch(b);
    scene_launch(e);
    double t = 0;
    int same = 1, moved = 0, parts_same = 1;
    for (int tick = 0; tick < ticks; tick++) {
        double dt = scene_dt(tick);
        t += dt;
        scene_steer(a, tick);
        scene_steer(b, tick);
        scene_steer(e, tick);
        if (c)
            scene_steer(c, tick);
        body_world_step(a, &seaa, t, dt, NULL, NULL, 0);
        body_world_step(b, &seab, t, dt, NULL, NULL, 0);
        parts_same &= step_in_parts(e, &se0, &se1, t, dt) && states_equal(a, e);
        if (c)
            body_world_step(c, &seac, t, dt, NULL, NULL, 0);
        same &= states_equal(a, b);
        if (tick + 1 == save_at) {
            /* Save every body of a and restore it into a new world. */
            c = body_world_new(16);
            for (int i = 0; i < body_world_count(a); i++) {
                struct body_state s;
                body_world_get(a, i, &s);
                if (body_world_restore(c, &s) != BODY_OK)
                    same = 0;
            }
        }
    }
    double far = 0; /* the longest way a body went: the scene is not at rest */
    for (int i = 0; i < body_world_count(a); i++) {
        struct body_state s0;
        body_world_get(a, i, &s0);
        far = fmax(far, hypot(s0.pos[0] - (-100 + 37.0 * i), s0.pos[2] - 20.0 * (i % 3)));
    }
    moved = far > 1;
    CHECK(same && moved, "the same launches and steering replayed: %d ticks bit-identical (%d bodies, one went %.1f m)",
          ticks, body_world_count(a), far);
    CHECK(c && states_equal(a, c), "saved at tick %d and restored into a new world: bit-identical %d ticks later",
          save_at, ticks - save_at);
    CHECK(parts_same, "stepped in two parts on two threads at once: bit-identical to the whole step, %d ticks", ticks);
    /* A digest of the final states (FNV-1a over their bytes, kind pointers
     * left out): equal across builds (-O1 with sanitizers, -O3) and
     * machines, since the step is + - * / and sqrt only. */
    uint64_t digest = 1469598103934665603ull;
    for (int i = 0; i < body_world_count(a); i++) {
        struct body_state x;
        body_world_get(a, i, &x);
        x.kind = NULL;
        const unsigned char *p = (const unsigned char *)&x;
        for (size_t j = 0; j < sizeof x; j++)
            digest = (digest ^ p[j]) * 1099511628211ull;
    }
    printf("     (final states digest %016llx over %d ticks)\n", (unsigned long long)digest, ticks);
    /* The check can fail: a tiny difference in one state stays different. */
    struct body_world *d = body_world_new(16);
    for (int i = 0; i < body_world_count(c); i++) {
        struct body_state s;
        body_world_get(c, i, &s);
        if (i == 2)
            s.vel[1] += 1e-9;
        body_world_restore(d, &s);
    }
    struct swell sd = scene_sea();
    struct body_sea sead = {swell_sample, &sd};
    double t2 = t;
    for (int tick = 0; tick < 30; tick++) {
        t2 += 1.0 / 30;
        body_world_step(c, &seac, t2, 1.0 / 30, NULL, NULL, 0);
        body_world_step(d, &sead, t2, 1.0 / 30, NULL, NULL, 0);
    }
    CHECK(!states_equal(c, d), "a state 1e-9 m/s off does not compare equal a second later");
    body_world_free(a);
    body_world_free(b);
    body_world_free(c);
    body_world_free(d);
    body_world_free(e);
}

/* ---- API ------------------------------------------------------------------------------------- */

static void test_api(void)
{
    check_section = "api";
    CHECK(body_world_new(0) == NULL && body_world_new(BODY_MAX_WORLD + 1) == NULL, "bad capacities refused");
    struct body_world *w = body_world_new(3);
    const struct body_kind *ball = body_kind_find("ball"), *dinghy = body_kind_find("dinghy");
    uint32_t id = 99, a = 0, b = 0;
    struct body_kind bad = *ball;
    bad.mass = -1;
    CHECK(body_launch(w, NULL, 0, 0, 0, &id) == BODY_ERR_KIND && body_launch(w, &bad, 0, 0, 0, &id) == BODY_ERR_KIND &&
              id == 99 && body_world_count(w) == 0 && body_world_next_id(w) == 1,
          "no kind / a kind of negative mass: %s, nothing changed", body_error_name(BODY_ERR_KIND));
    bad = *dinghy;
    bad.top_speed = 0;
    CHECK(body_launch(w, &bad, 0, 0, 0, &id) == BODY_ERR_KIND, "a powered kind without top speed: kind");
    CHECK(body_launch(w, ball, NAN, 0, 0, &id) == BODY_ERR_NOT_FINITE &&
              body_launch(w, ball, 0, INFINITY, 0, &id) == BODY_ERR_NOT_FINITE &&
              body_launch(w, ball, 0, 0, NAN, &id) == BODY_ERR_NOT_FINITE && body_world_count(w) == 0,
          "NaN / infinite position or heading: %s", body_error_name(BODY_ERR_NOT_FINITE));
    CHECK(body_launch(w, ball, BODY_WORLD_HALF_M + 0.01, 0, 0, &id) == BODY_ERR_RANGE &&
              body_launch(w, ball, 0, -BODY_WORLD_HALF_M - 0.01, 0, &id) == BODY_ERR_RANGE && body_world_count(w) == 0,
          "outside the world's bounds: %s", body_error_name(BODY_ERR_RANGE));
    enum body_error la = body_launch(w, dinghy, 0, 0, 30, &a), lb = body_launch(w, ball, 5, 5, 0, &b);
    CHECK(la == BODY_OK && a == 1 && lb == BODY_OK && b == 2, "ids ascend from 1: %u, %u", a, b);
    struct body_state s;
    s = state_of(w, a);
    double hd, p, r;
    body_attitude(&s, &hd, &p, &r);
    CHECK(fabs(hd - 30) < 1e-9 && fabs(p) < 1e-9 && fabs(r) < 1e-9, "launched at heading 30: attitude %.6f, %.2g, %.2g",
          hd, p, r);

    struct body_control ok = {0.5, -0.25}, c;
    body_steer(w, a, &ok);
    c = (struct body_control){NAN, 0};
    enum body_error e1 = body_steer(w, a, &c);
    c = (struct body_control){0, 1.5};
    enum body_error e2 = body_steer(w, a, &c);
    c = (struct body_control){-1.01, 0};
    enum body_error e3 = body_steer(w, a, &c);
    enum body_error e4 = body_steer(w, 77, &ok);
    s = state_of(w, a);
    CHECK(e1 == BODY_ERR_NOT_FINITE && e2 == BODY_ERR_RANGE && e3 == BODY_ERR_RANGE && e4 == BODY_ERR_NOT_FOUND &&
              s.control.throttle == 0.5 && s.control.rudder == -0.25,
          "steering NaN: %s, rudder 1.5 / throttle -1.01: %s, unknown id: %s; the control is unchanged",
          body_error_name(e1), body_error_name(e2), body_error_name(e4));

    uint32_t c3;
    CHECK(body_launch(w, ball, 0, 0, 0, &c3) == BODY_OK && body_launch(w, ball, 0, 0, 0, &id) == BODY_ERR_FULL &&
              body_world_count(w) == 3 && body_world_next_id(w) == 4,
          "a full world: %s, nothing changed", body_error_name(BODY_ERR_FULL));
    CHECK(body_remove(w, 42) == BODY_ERR_NOT_FOUND && body_world_count(w) == 3, "removing an unknown id: %s",
          body_error_name(BODY_ERR_NOT_FOUND));
    CHECK(body_remove(w, b) == BODY_OK && body_world_count(w) == 2 && body_remove(w, b) == BODY_ERR_NOT_FOUND,
          "remove id %u, and not twice", b);
    uint32_t d = 0;
    enum body_error ld = body_launch(w, ball, 0, 0, 0, &d);
    CHECK(ld == BODY_OK && d == 4, "ids are not reused: the next is %u", d);
    int ascending = 1;
    for (int i = 1; i < body_world_count(w); i++) {
        struct body_state x, y;
        body_world_get(w, i - 1, &x);
        body_world_get(w, i, &y);
        ascending &= x.id < y.id;
    }
    CHECK(ascending && body_world_get(w, body_world_count(w), &s) == -1 && body_world_get(w, -1, &s) == -1,
          "get: ascending ids, -1 out of range");

    /* Restore refusals. */
    struct body_state good = state_of(w, a), x;
    body_remove(w, a);
    x = good, x.id = 0;
    enum body_error r0 = body_world_restore(w, &x);
    x = good, x.id = d;
    enum body_error r1 = body_world_restore(w, &x);
    x = good, x.quat[0] = 0.9;
    enum body_error r2 = body_world_restore(w, &x);
    x = good, x.vel[2] = NAN;
    enum body_error r3 = body_world_restore(w, &x);
    x = good, x.pos[0] = 3000;
    enum body_error r4 = body_world_restore(w, &x);
    x = good, x.kind = NULL;
    enum body_error r5 = body_world_restore(w, &x);
    x = good, x.control.rudder = 2;
    enum body_error r6 = body_world_restore(w, &x);
    CHECK(r0 == BODY_ERR_RANGE && r1 == BODY_ERR_RANGE && r2 == BODY_ERR_RANGE && r3 == BODY_ERR_RANGE &&
              r4 == BODY_ERR_RANGE && r5 == BODY_ERR_KIND && r6 == BODY_ERR_RANGE && body_world_count(w) == 2,
          "restore refuses id 0, an id in use, a quaternion not unit, NaN, out of bounds, no kind, bad control");
    CHECK(body_world_restore(w, &good) == BODY_OK && body_world_count(w) == 3 && body_world_next_id(w) == 5,
          "restore an old id below the others: accepted, in order, the next id stays 5");
    body_world_get(w, 0, &x);
    CHECK(x.id == a && memcmp(&x, &good, sizeof x) == 0, "restored exactly");

    /* Ids never wrap: once UINT32_MAX is used, launches are refused. */
    struct body_world *w2 = body_world_new(4);
    x = good, x.id = UINT32_MAX;
    CHECK(body_world_restore(w2, &x) == BODY_OK && body_world_next_id(w2) == 0 &&
              body_launch(w2, ball, 0, 0, 0, &id) == BODY_ERR_FULL && body_world_count(w2) == 1,
          "after id UINT32_MAX the next id is 0 (none) and launches are refused: full");
    x.id = UINT32_MAX - 1;
    CHECK(body_world_restore(w2, &x) == BODY_OK, "a lower id can still be restored");
    body_world_free(w2);

    /* Bad steps do nothing. */
    struct body_state before = state_of(w, d), after;
    CHECK(body_world_step(w, NULL, 1, NAN, NULL, NULL, 0) == 0 && body_world_step(w, NULL, 1, -1, NULL, NULL, 0) == 0 &&
              body_world_step(w, NULL, NAN, 0.1, NULL, NULL, 0) == 0 &&
              body_world_step(w, NULL, 1, BODY_STEP_MAX_S * 2, NULL, NULL, 0) == 0,
          "dt NaN, negative, too long, t NaN: nothing");
    after = state_of(w, d);
    CHECK(memcmp(&before, &after, sizeof before) == 0, "... and nothing changed");
    /* A failing sea and a NaN sea are still water, bit for bit. */
    struct body_sea bad_seas[2] = {{failing_sample, NULL}, {nan_sample, NULL}};
    struct body_world *ws[3];
    for (int k = 0; k < 3; k++) {
        ws[k] = body_world_new(4);
        uint32_t i1, i2;
        body_launch(ws[k], dinghy, 0, 0, 10, &i1);
        body_launch(ws[k], ball, 10, 0, 0, &i2);
        struct body_state st = state_of(ws[k], i2);
        body_remove(ws[k], i2);
        st.pos[1] += 0.3; /* dropped, so that something moves */
        body_world_restore(ws[k], &st);
        struct body_control go = {1, 0.3};
        body_steer(ws[k], i1, &go);
        for (int i = 1; i <= 90; i++)
            body_world_step(ws[k], k ? &bad_seas[k - 1] : NULL, i / 30.0, 1.0 / 30, NULL, NULL, 0);
    }
    CHECK(states_equal(ws[0], ws[1]) && states_equal(ws[0], ws[2]), "a failing sea and a NaN sea are still water, bit "
          "for bit");
    for (int k = 0; k < 3; k++)
        body_world_free(ws[k]);
    CHECK(strcmp(body_error_name(BODY_OK), "ok") == 0 && strcmp(body_error_name(BODY_ERR_NO_MEMORY), "no_memory") == 0,
          "error names");
    body_world_free(w);

    /* The frames: heading 90 is east (-x); bow up is positive pitch, starboard
     * down positive roll. */
    struct body_world *wf = body_world_new(2);
    uint32_t fe;
    body_launch(wf, dinghy, 0, 0, 90, &fe);
    struct body_control ahead = {1, 0};
    body_steer(wf, fe, &ahead);
    double tf = 0;
    step_for(wf, NULL, &tf, 10, 1.0 / 30);
    struct body_state sf = state_of(wf, fe);
    CHECK(sf.pos[0] < -5 && fabs(sf.pos[2]) < 1e-6, "heading 90 runs east (-x): at x = %.2f m, z = %.2g m after 10 s",
          sf.pos[0], sf.pos[2]);
    struct body_state tilt = sf;
    double half = 5 / DEG / 2;
    /* -5 deg about +x: bow up */
    tilt.quat[0] = cos(half), tilt.quat[1] = -sin(half), tilt.quat[2] = 0, tilt.quat[3] = 0;
    double th, tp, tr;
    body_attitude(&tilt, &th, &tp, &tr);
    CHECK(fabs(tp - 5) < 1e-9 && fabs(tr) < 1e-9 && fabs(th) < 1e-9, "bow up 5 deg: pitch %+.6f, roll %+.2g", tp, tr);
    /* +5 deg about the bow: port up */
    tilt.quat[0] = cos(half), tilt.quat[1] = 0, tilt.quat[3] = sin(half);
    body_attitude(&tilt, &th, &tp, &tr);
    CHECK(fabs(tr - 5) < 1e-9 && fabs(tp) < 1e-9, "starboard down 5 deg: roll %+.6f, pitch %+.2g", tr, tp);
    body_world_free(wf);

    /* The world's edge holds a body: a dinghy at full ahead toward west
     * (+x) from 20 m inside stops at the edge, still inside. */
    struct body_world *we = body_world_new(1);
    uint32_t e;
    body_launch(we, dinghy, BODY_WORLD_HALF_M - 20, 0, 270, &e);
    struct body_control full = {1, 0};
    body_steer(we, e, &full);
    double t = 0;
    step_for(we, NULL, &t, 40, 1.0 / 30);
    struct body_state se = state_of(we, e);
    CHECK(se.pos[0] == BODY_WORLD_HALF_M && se.vel[0] <= 0 && body_world_count(we) == 1,
          "held at the edge: x = %.3f m, outward velocity %.3g m/s", se.pos[0], se.vel[0]);
    body_world_free(we);
}

#define RUN(fn)                                                       \
    do {                                                              \
        if (only && strcmp(only, #fn) != 0)                           \
            break;                                                    \
        double t0_ = seconds();                                       \
        fn();                                                         \
        printf("     (%s: %.2f s)\n", #fn, seconds() - t0_);          \
    } while (0)

int main(void)
{
    check_verbose = 1; /* the passing lines carry the measured values */
    quick = check_quick();
    only = getenv("OCEAN_TEST_ONLY");
    if (only && !*only)
        only = NULL;
    if (quick)
        printf("quick mode (OCEAN_TEST_QUICK): shorter runs, one powered kind\n");
    RUN(test_table);
    RUN(test_archimedes);
    RUN(test_heave);
    RUN(test_waves);
    RUN(test_storm);
    RUN(test_powered);
    RUN(test_determinism);
    RUN(test_api);
    return check_done();
}

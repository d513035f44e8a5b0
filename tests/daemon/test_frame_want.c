/* test_frame_want.c — which layers a tick builds (server/tick/frame_want.c),
 * checked on hand-made plans and demand: due groups only, the planned LOD,
 * a stream for temporal clients, intra tiles for others and edges, the
 * codec rung, keyframe wishes, probes stepped on every cascade. */
#include <string.h>

#include "../common/check.h"
#include "tick_internal.h"

static struct demand_snapshot demand_none(void)
{
    struct demand_snapshot d;
    memset(&d, 0, sizeof d);
    return d;
}

int main(void)
{
    const int h0 = layer_key(OCEAN_HEIGHT, 0, 3), dx0 = layer_key(OCEAN_DX, 0, 3);
    const int h1c1 = layer_key_cascade(1, OCEAN_HEIGHT, 1, 2);
    const int g0 = plan_group(0, 3), g1 = plan_group(1, 2);
    struct plan plan;
    memset(&plan, 0, sizeof plan);
    plan.fields[g0] = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX);
    plan.lod[g0] = 1; /* degraded: encoded a LOD coarser */
    plan.rate[g0] = 1;
    plan.fields[g1] = OCEAN_FIELD_BIT(OCEAN_HEIGHT);
    plan.lod[g1] = 1;
    plan.rate[g1] = 1;
    bool due[PLAN_GROUPS] = { false };
    due[g0] = true;

    struct demand_snapshot d = demand_none();
    d.demand[h0] = 3;
    d.tdemand[h0] = 2;   /* two temporal clients, one intra */
    d.key_want[h0] = 1;
    d.demand[dx0] = 1;
    d.tdemand[dx0] = 1;  /* temporal only */
    d.demand[h1c1] = 1;  /* group g1, not due */
    d.any = true;
    struct frame_want w;
    memset(&w, 0, sizeof w);
    frame_want_build(&plan, due, &d, 0, &w);
    CHECK(w.nkeys == 2, "the due group's two keys, not the other group's (%d)", w.nkeys);
    CHECK(w.keys[0] == h0 && w.keys[1] == dx0, "keys in key order (%d, %d)", w.keys[0], w.keys[1]);
    CHECK(w.lod[0] == 1 && w.lod[1] == 1, "encoded at the planned LOD");
    CHECK(w.fields == (OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX)), "fields 0x%x", w.fields);
    CHECK(w.cfields[0] == w.fields && w.cfields[1] == 0, "cascade 1 is not stepped (0x%x)", w.cfields[1]);
    CHECK(w.temporal[h0] && w.intra[h0], "height: a stream, and intra tiles for the intra client");
    CHECK(w.temporal[dx0] && !w.intra[dx0], "dx: a stream only");
    CHECK(w.tclients[h0] == 2 && w.iclients[h0] == 1 && w.kclients[h0] == 1, "height's client counts");

    /* The codec rung (a temporal group at its own LOD, served intra): everyone intra, no stream. */
    plan.lod[g0] = 0;
    plan.temporal[g0] = plan.intra[g0] = true;
    memset(&w, 0, sizeof w);
    frame_want_build(&plan, due, &d, 0, &w);
    CHECK(!w.temporal[h0] && w.intra[h0] && !w.temporal[dx0] && w.intra[dx0], "the codec rung serves intra");
    CHECK(w.lod[0] == 0, "the codec rung keeps the group's own LOD");
    plan.intra[g0] = false;

    /* An edge wants dx: intra tiles every tick, counted as a taker that never leaves. */
    d.remote[dx0 >> 3] |= (uint8_t)(1u << (dx0 & 7));
    memset(&w, 0, sizeof w);
    frame_want_build(&plan, due, &d, 0, &w);
    CHECK(w.intra[dx0] && w.iclients[dx0] == 65535, "an edge takes intra tiles (%u)", w.iclients[dx0]);

    /* Nothing due, probes only: every cascade stepped for height/dx/dz, nothing encoded. */
    const unsigned probe = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ);
    bool none[PLAN_GROUPS] = { false };
    memset(&w, 0, sizeof w);
    frame_want_build(&plan, none, &d, probe, &w);
    CHECK(w.nkeys == 0 && w.cfields[3] == probe && w.fields == probe, "probes step every cascade, encode nothing");

    /* Nothing due, no probes: nothing at all. */
    memset(&w, 0, sizeof w);
    frame_want_build(&plan, none, &d, 0, &w);
    CHECK(w.nkeys == 0 && w.fields == 0, "an off tick builds nothing");
    return check_done();
}

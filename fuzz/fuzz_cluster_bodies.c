/* fuzz_cluster_bodies.c — libFuzzer target: what a cluster reads of the
 * floating bodies from NATS. The first byte picks the reader: 0, a tick's
 * BODY_SECTION envelope body (edge_bodies_add_section: accepted only as a
 * whole section of 48-byte records, then handed out for its seq and no
 * other); else, the JetStream record's "bodies" (state_bodies_parse: all or
 * none; an accepted set has distinct ids below next_id, and prints and
 * parses back to the same set). */
#include <cjson/cJSON.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "edge_bodies.h"
#include "oc_proto.h"
#include "state.h"

/* The daemon's (body_tick.c, cluster_assemble.c), for edge_bodies.c alone. */
void body_snap_ref(struct body_snap *b) { atomic_fetch_add(&b->refs, 1); }
void body_snap_unref(struct body_snap *b)
{
    if (b && atomic_fetch_sub(&b->refs, 1) == 1)
        free(b);
}
void cl_frame_set_free(struct cl_frame_set *s) { (void)s; }

static void check(int ok)
{
    if (!ok)
        abort();
}

static void section(const uint8_t *data, size_t size)
{
    struct edge_bodies *eb = edge_bodies_new();
    check(eb != NULL);
    if (edge_bodies_add_section(eb, data, size) == 0) {
        uint64_t seq = 0;
        for (int i = 0; i < 8; i++)
            seq |= (uint64_t)data[i] << (8 * i);
        struct body_snap *b = edge_bodies_for(eb, seq);
        check(b && b->count >= 1 && b->count <= OC_BODY_MAX_RECORDS && b->section_len == size - 8 &&
              b->section_len == oc_body_section_size(b->count) && memcmp(b->section, data + 8, size - 8) == 0);
        body_snap_unref(b);
        check(edge_bodies_for(eb, seq + 1) == NULL);
    }
    edge_bodies_free(eb);
}

static void record(const uint8_t *data, size_t size)
{
    cJSON *root = cJSON_ParseWithLength((const char *)data, size);
    if (!root)
        return;
    struct state_bodies sb;
    char err[256];
    if (state_bodies_parse(root, &sb, err, sizeof err) == 0) {
        for (int i = 0; i < sb.n; i++) {
            check(sb.b[i].st.id >= 1 && sb.b[i].st.id < sb.next_id && sb.b[i].st.kind);
            for (int k = 0; k < i; k++)
                check(sb.b[k].st.id != sb.b[i].st.id);
        }
        cJSON *built = state_bodies_json(&sb);
        char *text = cJSON_PrintUnformatted(built); /* raw numbers: read back from text */
        cJSON_Delete(built);
        cJSON *again = text ? cJSON_Parse(text) : NULL;
        free(text);
        struct state_bodies sb2;
        check(again && state_bodies_parse(again, &sb2, err, sizeof err) == 0 && sb2.n == sb.n &&
              sb2.next_id == sb.next_id);
        for (int i = 0; i < sb.n; i++)
            check(memcmp(&sb.b[i].st.pos, &sb2.b[i].st.pos, sizeof sb.b[i].st.pos) == 0 &&
                  strcmp(sb.b[i].origin, sb2.b[i].origin) == 0 && strcmp(sb.b[i].resume, sb2.b[i].resume) == 0);
        cJSON_Delete(again);
        state_bodies_free(&sb2);
        state_bodies_free(&sb);
    } else {
        check(strncmp(err, "bad_body", 8) == 0 && sb.n == 0 && sb.b == NULL);
    }
    cJSON_Delete(root);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    if (data[0] == 0)
        section(data + 1, size - 1);
    else
        record(data + 1, size - 1);
    return 0;
}

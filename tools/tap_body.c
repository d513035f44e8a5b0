/* tap_body.c — ocean-tap's floating bodies (PROTOCOL.md §3.5, §7.6):
 *   --launch KIND --at X,Z [--heading DEG]   launch one (the server's launched reply on stdout)
 *   --body ID [--resume KEY]                 claim one back (with KEY), or steer it (without)
 *   --throttle T --rudder R                  steer it once it is ours
 *   --follow [--csv] [--ticks N]             one line per tick from the frame header's records
 *   --bodies                                 the bodies now (hello), one JSON line each
 * Our body (launched or claimed) is removed at the end unless --keep. */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tap.h"

int body_mode(const struct opts *o)
{
    return o->launch_kind || o->body || o->list_bodies;
}

static int id_of(cJSON *msg)
{
    cJSON *j = cJSON_GetObjectItemCaseSensitive(msg, "id");
    return cJSON_IsNumber(j) ? j->valueint : -1;
}

static cJSON *body_request(struct session *s, const char *type, int id)
{
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "type", type);
    cJSON_AddNumberToObject(j, "id", id);
    if (s->body_id) cJSON_AddNumberToObject(j, "body", s->body_id);
    if (s->o->token) cJSON_AddStringToObject(j, "token", s->o->token);
    return j;
}

/* The hello: who we are (our body's owner) and, for --bodies, the list. */
void body_hello(struct session *s, cJSON *hello)
{
    cJSON *cid = cJSON_GetObjectItemCaseSensitive(hello, "client_id");
    if (cJSON_IsString(cid)) snprintf(s->client_id, sizeof s->client_id, "%s", cid->valuestring);
    if (s->o->list_bodies) {
        cJSON *b;
        cJSON_ArrayForEach(b, cJSON_GetObjectItemCaseSensitive(hello, "bodies")) {
            char *out = cJSON_PrintUnformatted(b);
            if (out) puts(out);
            free(out);
        }
        fflush(stdout);
    }
}

static void send_steer(struct session *s)
{
    cJSON *j = body_request(s, "steer", ID_STEER);
    if (s->o->has_throttle) cJSON_AddNumberToObject(j, "throttle", s->o->throttle);
    if (s->o->has_rudder) cJSON_AddNumberToObject(j, "rudder", s->o->rudder);
    s->stage = ST_STEER;
    send_json(s, j);
}

/* Every frame: the smallest subscription there is, at the full tick rate. */
static void send_body_subscribe(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *tiles = cJSON_CreateArray(), *t00 = cJSON_CreateArray();
    cJSON_AddStringToObject(j, "type", "subscribe");
    cJSON_AddNumberToObject(j, "id", ID_QUIET);
    cJSON_AddItemToArray(cJSON_AddArrayToObject(j, "fields"), cJSON_CreateString("height"));
    cJSON_AddNumberToObject(j, "lod", OC_MAX_LOD);
    cJSON_AddItemToArray(t00, cJSON_CreateNumber(0));
    cJSON_AddItemToArray(t00, cJSON_CreateNumber(0));
    cJSON_AddItemToArray(tiles, t00);
    cJSON_AddItemToObject(j, "tiles", tiles);
    send_json(s, j);
}

static void start_follow(struct session *s)
{
    s->stage = ST_RUN;
    s->st.t0 = s->st.last_report = s->last_frame = now_s();
    if (!s->o->follow) finish_body(s, EXIT_OK);
}

/* After hello (and any --set): the first body request. */
void body_start(struct session *s)
{
    const struct opts *o = s->o;
    if (o->list_bodies) { finish(s, EXIT_OK); return; }
    if (o->follow) send_body_subscribe(s);
    s->stage = ST_BODY;
    if (o->launch_kind) {
        cJSON *j = body_request(s, "launch", ID_LAUNCH);
        cJSON_AddStringToObject(j, "kind", o->launch_kind);
        cJSON_AddNumberToObject(j, "x", o->at[0]);
        cJSON_AddNumberToObject(j, "z", o->at[1]);
        cJSON_AddNumberToObject(j, "heading", o->heading);
        send_json(s, j);
    } else {
        s->body_id = (uint32_t)o->body;
        if (o->resume) {
            cJSON *j = body_request(s, "claim", ID_CLAIM);
            cJSON_AddStringToObject(j, "resume", o->resume);
            send_json(s, j);
        } else if (o->has_throttle || o->has_rudder) {
            send_steer(s);
        } else {
            start_follow(s); /* follow someone's body */
        }
    }
}

/* The end of our part: remove our body (unless --keep), then exit with code. */
void finish_body(struct session *s, int code)
{
    if (s->own && !s->o->keep && s->stage != ST_REMOVE && s->stage != ST_DONE && s->wsi) {
        s->body_code = code;
        s->stage = ST_REMOVE;
        send_json(s, body_request(s, "remove", ID_REMOVE));
        return;
    }
    finish(s, code);
}

/* Ctrl-C: 1 when it starts the removal of our body (the loop goes on until it is answered). */
int body_interrupt(struct session *s)
{
    if (!body_mode(s->o) || !s->own || s->o->keep || s->stage == ST_REMOVE || s->stage == ST_DONE) return 0;
    finish_body(s, EXIT_OK);
    return s->stage == ST_REMOVE;
}

/* Text messages of the body requests: 1 when handled. */
int body_on_text(struct session *s, cJSON *msg, const char *t)
{
    int id = id_of(msg);
    cJSON *b = cJSON_GetObjectItemCaseSensitive(msg, "body");
    if (!strcmp(t, "error") && (id == ID_LAUNCH || id == ID_CLAIM || id == ID_STEER || id == ID_REMOVE)) {
        print_error(msg, id == ID_LAUNCH ? "launch rejected" : id == ID_CLAIM ? "claim rejected"
                         : id == ID_STEER ? "steer rejected" : "remove rejected");
        if (id == ID_REMOVE) { finish(s, EXIT_REJECTED); return 1; }
        finish_body(s, EXIT_REJECTED);
        return 1;
    }
    if ((!strcmp(t, "launched") && id == ID_LAUNCH) || (!strcmp(t, "claimed") && id == ID_CLAIM)) {
        if (!cJSON_IsNumber(b) || b->valuedouble < 1) { fail(s, EXIT_PROTOCOL, "%s without a body", t); return 1; }
        s->body_id = (uint32_t)b->valuedouble;
        s->own = 1;
        cJSON *out = cJSON_CreateObject();
        cJSON_AddNumberToObject(out, t[0] == 'l' ? "launched" : "claimed", s->body_id);
        cJSON *key = cJSON_GetObjectItemCaseSensitive(msg, "resume");
        cJSON_AddStringToObject(out, "resume", cJSON_IsString(key) ? key->valuestring : s->o->resume ? s->o->resume : "");
        cJSON_AddStringToObject(out, "owner", s->client_id);
        char *text = cJSON_PrintUnformatted(out);
        cJSON_Delete(out);
        /* With --csv stdout is the table's: the key goes to stderr. */
        if (text) { fprintf(s->o->csv ? stderr : stdout, "%s\n", text); fflush(s->o->csv ? stderr : stdout); }
        free(text);
        if (s->o->has_throttle || s->o->has_rudder) send_steer(s);
        else start_follow(s);
        return 1;
    }
    if (!strcmp(t, "steered") && id == ID_STEER) {
        start_follow(s);
        return 1;
    }
    if (!strcmp(t, "removed") && id == ID_REMOVE) {
        s->own = 0;
        finish(s, s->body_code);
        return 1;
    }
    if (!strcmp(t, "bodies")) {
        if (!s->body_id || s->stage == ST_REMOVE) return 1;
        cJSON *r;
        cJSON_ArrayForEach(r, cJSON_GetObjectItemCaseSensitive(msg, "removed")) {
            cJSON *rb = cJSON_GetObjectItemCaseSensitive(r, "body"), *why = cJSON_GetObjectItemCaseSensitive(r, "reason");
            if (cJSON_IsNumber(rb) && (uint32_t)rb->valuedouble == s->body_id) {
                s->own = 0;
                fail(s, EXIT_BODY_GONE, "body %u left the sea: %s", s->body_id,
                     cJSON_IsString(why) ? why->valuestring : "?");
            }
        }
        return 1;
    }
    return 0;
}

/* Heading (compass: north = +z, east = -x), pitch (bow up +) and roll (port up +), degrees,
 * of a body -> world quaternion; body +z = bow, +y = up, +x = port. */
static void attitude(const float q[4], double *heading, double *pitch, double *roll)
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    double bx = 2 * (x * z + w * y), by = 2 * (y * z - w * x), bz = 1 - 2 * (x * x + y * y);
    double port_y = 2 * (x * y + w * z), up_y = 1 - 2 * (x * x + z * z);
    *heading = fmod(atan2(-bx, bz) * 180 / M_PI + 360.0, 360.0);
    *pitch = asin(by > 1 ? 1 : by < -1 ? -1 : by) * 180 / M_PI;
    *roll = atan2(port_y, up_y) * 180 / M_PI;
}

void body_on_frame(struct session *s, const uint8_t *data, size_t len)
{
    static struct oc_body_record rec[OC_BODY_MAX_RECORDS];
    struct oc_frame_header fh;
    if (oc_frame_header_read(data, len, &fh) < 0) { fail(s, EXIT_PROTOCOL, "bad frame header"); return; }
    int n = oc_body_section_read(data, len, rec, OC_BODY_MAX_RECORDS);
    if (n < 0) { fail(s, EXIT_PROTOCOL, "bad BODY section in frame %llu (%d)", (unsigned long long)fh.seq, n); return; }
    if (s->stage != ST_RUN || !s->o->follow || !s->body_id) return;
    if (s->ticks_done && fh.seq <= s->last_seq) return; /* a later part of the same tick */
    for (int i = 0; i < n; i++) {
        if (rec[i].id != s->body_id) continue;
        const struct oc_body_record *r = &rec[i];
        double hd, pt, rl, speed = hypot(r->vel[0], r->vel[2]);
        attitude(r->quat, &hd, &pt, &rl);
        if (s->o->csv) {
            if (!s->csv_header_done) puts("seq,sim_time,id,x,y,z,heading,pitch,roll,speed");
            s->csv_header_done = 1;
            printf("%llu,%.4f,%u,%.3f,%.3f,%.3f,%.2f,%.2f,%.2f,%.3f\n", (unsigned long long)fh.seq, fh.sim_time,
                   r->id, r->pos[0], r->pos[1], r->pos[2], hd, pt, rl, speed);
        } else {
            printf("{\"seq\":%llu,\"sim_time\":%.4f,\"id\":%u,\"x\":%.3f,\"y\":%.3f,\"z\":%.3f,\"heading\":%.2f,"
                   "\"pitch\":%.2f,\"roll\":%.2f,\"speed\":%.3f,\"throttle\":%.3f,\"rudder\":%.3f,\"adrift\":%s}\n",
                   (unsigned long long)fh.seq, fh.sim_time, r->id, r->pos[0], r->pos[1], r->pos[2], hd, pt, rl, speed,
                   r->throttle / 127.0, r->rudder / 127.0, r->flags & OC_BODY_FLAG_ADRIFT ? "true" : "false");
        }
        fflush(stdout);
        s->last_seq = fh.seq;
        s->last_frame = now_s();
        if (++s->ticks_done >= s->o->ticks && s->o->ticks > 0) finish_body(s, EXIT_OK);
        return;
    }
}

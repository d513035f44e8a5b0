/* test_seq_guard.c — the edge's belief about frame numbers (server/roles/
 * seq_guard.h): a live stream is always followed; a rogue layer or a burst
 * of future frames never is; a restarted sim's new timeline is adopted
 * within a second. Pure: times are given, not measured. */
#include <stdio.h>

#include "../common/check.h"
#include "seq_guard.h"

#define RATE 30.0

/* ticks of a live stream from seq at time t (3 layers each); returns how many were not accepted */
static int feed(struct seq_guard *g, uint64_t *seq, double *t, int ticks, int *restarts)
{
    int bad = 0;
    for (int i = 0; i < ticks; i++) {
        for (int l = 0; l < 3; l++) {
            enum seq_verdict v = seq_guard_check(g, *seq, *t, RATE);
            bad += v == SEQ_REFUSE;
            if (restarts)
                *restarts += v == SEQ_RESTART;
        }
        (*seq)++;
        *t += 1 / RATE;
    }
    return bad;
}

int main(void)
{
    struct seq_guard g = { 0 };
    uint64_t seq = 53000000000ull; /* --role sim counts from the wall clock */
    double t = 100;
    CHECK(feed(&g, &seq, &t, 60, NULL) == 0, "a live stream is followed");

    /* One rogue layer far in the future: refused, the stream goes on. */
    CHECK(seq_guard_check(&g, seq + 2000000000ull, t, RATE) == SEQ_REFUSE, "a layer 2e9 ahead is refused");
    CHECK(feed(&g, &seq, &t, 30, NULL) == 0, "the stream is followed after a rogue layer");

    /* A burst of three complete future frames, then the live stream. */
    int bad = 0;
    for (int f = 0; f < 3; f++)
        for (int l = 0; l < 3; l++)
            bad += seq_guard_check(&g, seq + 2000000000ull + (uint64_t)f, t, RATE) == SEQ_REFUSE;
    CHECK(bad == 9, "every layer of a burst of future frames is refused (%d of 9)", bad);
    CHECK(feed(&g, &seq, &t, 30, NULL) == 0, "the stream is followed after a burst");

    /* The same future seq repeated for a second is still not a stream. */
    for (int i = 0; i < 40; i++)
        CHECK(seq_guard_check(&g, seq + 500000, t + i / RATE, RATE) == SEQ_REFUSE, "a repeated seq is never adopted");
    t += 40 / RATE;
    seq += 40;

    /* Stragglers of the tick before, and a little jitter ahead, belong to the stream. */
    CHECK(seq_guard_check(&g, seq - 2, t, RATE) == SEQ_ACCEPT, "a straggler is accepted");
    CHECK(seq_guard_check(&g, seq + 5, t, RATE) == SEQ_ACCEPT, "a layer a little ahead (jitter) is accepted");
    seq += 6;
    t += 6 / RATE;

    /* The sim is down 10 s and comes back on the wall clock: seq +300, in time. */
    t += 10;
    seq += 300;
    CHECK(feed(&g, &seq, &t, 30, NULL) == 0, "a sim back after an outage is followed");

    /* A standby or restarted sim whose clock is 20 s behind: adopted within a second. */
    uint64_t other = seq - 600;
    int restarts = 0;
    double t0 = t;
    int refused = feed(&g, &other, &t, 45, &restarts);
    CHECK(restarts == 1, "another timeline is adopted once (%d)", restarts);
    CHECK(refused > 0 && refused / 3.0 / RATE <= 1.0, "adopted within a second (%.2f s refused)", refused / 3.0 / RATE);
    CHECK(feed(&g, &other, &t, 30, NULL) == 0, "the adopted timeline is followed");
    (void)t0;

    /* A guard that has seen nothing believes the first seq. */
    struct seq_guard fresh = { 0 };
    CHECK(seq_guard_check(&fresh, 7, 0, RATE) == SEQ_ACCEPT, "the first seq is believed");
    return check_done();
}

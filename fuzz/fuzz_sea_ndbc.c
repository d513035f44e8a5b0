/* fuzz_sea_ndbc.c — libFuzzer target: NDBC's realtime and historical readers
 * (tools/sea_ndbc.c), the text of five files as a stranger's server may send it.
 * Input: one byte (bit 0: historical, bit 1: ask for a time), then the five
 * files separated by NUL bytes (missing ones are empty). Invariants: an accepted
 * sea passes the document's checks again and becomes JSON; a refused one has a code. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    int hist = data[0] & 1, timed = data[0] & 2;
    const char *p = (const char *)data + 1, *end = (const char *)data + size;
    char *bufs[5];
    struct sea_text t[5];
    for (int k = 0; k < 5; k++) {
        const char *z = p < end ? memchr(p, 0, (size_t)(end - p)) : NULL;
        size_t n = p < end ? (size_t)((z ? z : end) - p) : 0;
        bufs[k] = malloc(n + 1); /* exact size: ASan sees a read past the NUL */
        if (!bufs[k]) abort();
        if (n) memcpy(bufs[k], p, n);
        bufs[k][n] = 0;
        t[k] = (struct sea_text){k ? "f" : "f0", bufs[k], n};
        p += n + 1;
    }
    struct sea_doc *d = malloc(sizeof *d);
    struct sea_err e = {0};
    if (!d) abort();
    const char *when = timed ? "2026-12-01T19:40:00Z" : NULL;
    int rc = hist ? sea_ndbc_historical(t, "46026", when, d, &e) : sea_ndbc_realtime(t, "46026", when, d, &e);
    if (rc == 0) {
        struct sea_err again = {0};
        if (e.code[0] || sea_doc_check(d, "f0", &again) != 0) abort();
        cJSON *j = sea_doc_json(d);
        if (!j) abort();
        cJSON_Delete(j);
    } else if (!e.code[0]) {
        abort();
    }
    free(d);
    for (int k = 0; k < 5; k++) free(bufs[k]);
    return 0;
}

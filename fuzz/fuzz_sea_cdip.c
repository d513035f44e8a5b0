/* fuzz_sea_cdip.c — libFuzzer target: the reader of CDIP's OPeNDAP text
 * (tools/sea_cdip.c). Input: one byte (bit 0: ask for a time), then the answer's
 * text. Invariants: an accepted record passes the document's checks again; a refused
 * one has a code. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    char *text = malloc(size);
    if (!text) abort();
    memcpy(text, data + 1, size - 1);
    text[size - 1] = 0;
    struct sea_text t = {"ascii", text, strnlen(text, size - 1)};
    struct sea_doc *d = malloc(sizeof *d);
    struct sea_err e = {0};
    if (!d) abort();
    if (sea_cdip(&t, "100p1", data[0] & 1 ? "2025-12-01T20:30:00Z" : NULL, d, &e) == 0) {
        struct sea_err again = {0};
        if (e.code[0] || sea_doc_check(d, "ascii", &again) != 0) abort();
    } else if (!e.code[0]) {
        abort();
    }
    free(d);
    free(text);
    return 0;
}

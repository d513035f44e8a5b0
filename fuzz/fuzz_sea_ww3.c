/* fuzz_sea_ww3.c — libFuzzer target: the WAVEWATCH III point-spectrum reader
 * (tools/sea_ww3.c). Input: the file's text. Invariants: every accepted time passes
 * the document's checks again, in 1..SEA_MAX_TIMES documents; a refused file has a code. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    if (!text) abort();
    if (size) memcpy(text, data, size);
    text[size] = 0;
    struct sea_text t = {"spec", text, strnlen(text, size)};
    struct sea_doc *docs = NULL;
    struct sea_err e = {0};
    int n = 0;
    if (sea_ww3(&t, NULL, &docs, &n, &e) == 0) {
        if (e.code[0] || n < 1 || n > SEA_MAX_TIMES) abort();
        for (int i = 0; i < n; i++) {
            struct sea_err again = {0};
            if (sea_doc_check(&docs[i], "spec", &again) != 0) abort();
        }
    } else if (!e.code[0]) {
        abort();
    }
    free(docs);
    free(text);
    return 0;
}

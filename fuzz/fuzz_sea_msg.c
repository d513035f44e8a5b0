/* fuzz_sea_msg.c — libFuzzer target: the `sea` message's document
 * (server/control/sea_msg.c) from any JSON text, as a client or a state file
 * sends it. Whatever the input: a refusal has a code and a message; an
 * accepted document passed the library's check, prints back (sea_doc_json)
 * to text that reads back to the same sea, and has a summary. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "control.h"
#include "sea_msg.h"

static void check(int ok)
{
    if (!ok)
        abort();
}

static struct sea_spectrum a, b; /* 83 kB each: not on the stack */

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct ctl_error e;
    cJSON *root = control_parse_object((const char *)data, size, &e);
    if (!root)
        return 0;
    const cJSON *doc = cJSON_GetObjectItemCaseSensitive(root, "sea");
    if (!doc)
        doc = root;
    memset(&e, 0, sizeof e);
    if (sea_doc_parse(doc, &a, &e) != 0) {
        check(e.code && e.code[0] && e.message[0]);
        cJSON_Delete(root);
        return 0;
    }
    cJSON_Delete(root);
    char msg[200];
    check(sea_spectrum_check(&a, msg, sizeof msg) == SEA_OK);
    char *text = control_print(sea_doc_json(&a));
    check(text != NULL);
    cJSON *again = cJSON_Parse(text);
    free(text);
    check(again && sea_doc_parse(again, &b, &e) == 0);
    cJSON_Delete(again);
    check(a.form == b.form && a.bands == b.bands && a.directions == b.directions && a.tail == b.tail &&
          !memcmp(a.frequency, b.frequency, sizeof(double) * (size_t)a.bands) && !strcmp(a.source, b.source));
    cJSON *sum = sea_summary_json(&a, NULL, 1);
    check(sum != NULL);
    cJSON_Delete(sum);
    return 0;
}

/* fuzz_config.c — libFuzzer target: the config-file loader. Each input is
 * applied, as the text of a --config file, onto the daemon's defaults
 * through config_apply_text, the path config_load takes after reading the
 * file. A rejected file must say why and change nothing; an accepted one
 * must leave every parameter in range and the set valid. */
#include <stdint.h>
#include <stdlib.h>

#include "config.h"

static struct daemon_config base_dc;
static struct ocean_params base_p;

static void load_defaults(void)
{
    char *argv[] = { "oceand", "--state-file", "none", NULL };
    struct config_result res;
    char err[512];
    if (config_load(3, argv, &base_dc, &base_p, &res, err, sizeof err) != 0)
        abort();
}

/* Plain byte comparison, left out of coverage tracing: libFuzzer's memcmp
 * hook on these 4 KiB structs cost more than the code under test. */
__attribute__((no_sanitize("coverage"))) static int same_bytes(const void *a, const void *b, size_t n)
{
    const unsigned char *x = a, *y = b;
    unsigned char diff = 0;
    for (size_t i = 0; i < n; i++)
        diff |= x[i] ^ y[i];
    return diff == 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    if (!ready) {
        load_defaults();
        ready = 1;
    }
    struct daemon_config dc = base_dc;
    struct ocean_params p = base_p;
    char err[512] = "";
    if (config_apply_text(&dc, &p, (const char *)data, size, err, sizeof err) == 0) {
        for (size_t i = 0; i < param_count; i++) {
            double v = param_get(&p, &param_table[i]);
            if (!(v >= param_table[i].min && v <= param_table[i].max))
                abort();
        }
        if (params_validate(&p, err, sizeof err) != 0)
            abort();
    } else if (err[0] == '\0' || !same_bytes(&dc, &base_dc, sizeof dc) || !same_bytes(&p, &base_p, sizeof p)) {
        abort(); /* an error must say why and leave everything as it was */
    }
    return 0;
}

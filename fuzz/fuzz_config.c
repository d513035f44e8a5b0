/* fuzz_config.c — libFuzzer target: the --config file loader. The input is
 * written to a file (the loader reads paths) and loaded as the daemon would,
 * with no state file so nothing else is read. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "config.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char path[64];
    if (!path[0])
        snprintf(path, sizeof path, "/dev/shm/oceand-fuzz-config-%d.json", (int)getpid());
    FILE *f = fopen(path, "wb");
    if (!f)
        return 0;
    fwrite(data, 1, size, f);
    fclose(f);

    char *argv[] = { "oceand", "--state-file", "none", "--config", path, NULL };
    struct daemon_config dc;
    struct ocean_params p;
    struct config_result res;
    char err[512];
    if (config_load(5, argv, &dc, &p, &res, err, sizeof err) == 0) {
        for (size_t i = 0; i < param_count; i++) {
            double v = param_get(&p, &param_table[i]);
            if (!(v >= param_table[i].min && v <= param_table[i].max))
                abort();
        }
        if (params_validate(&p, err, sizeof err) != 0)
            abort();
    } else if (err[0] == '\0') {
        abort(); /* an error must say why */
    }
    return 0;
}

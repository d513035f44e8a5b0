/* slurp.h — a whole file into memory, for the test helpers that read
 * JSON or frames from files (header-only: no link step to add).
 *
 * slurp(path, &len): a malloc'd buffer of the file's bytes with a NUL after
 * them (so JSON text can be parsed in place), its length in *len; NULL if the
 * file cannot be opened, sized or read whole (*len is then untouched). */
#ifndef OCEAND_TESTS_SLURP_H
#define OCEAND_TESTS_SLURP_H

#include <stdio.h>
#include <stdlib.h>

__attribute__((unused))
static char *slurp(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    char *b = NULL;
    long n = fseek(f, 0, SEEK_END) == 0 ? ftell(f) : -1;
    if (n >= 0 && fseek(f, 0, SEEK_SET) == 0)
        b = malloc((size_t)n + 1);
    if (b && fread(b, 1, (size_t)n, f) != (size_t)n) {
        free(b);
        b = NULL;
    }
    fclose(f);
    if (b) {
        b[n] = 0;
        *len = (size_t)n;
    }
    return b;
}

#endif

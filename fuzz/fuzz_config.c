/* fuzz_config.c — libFuzzer target: the config-file loader. Each input is
 * applied, as the text of a --config file, onto the daemon's defaults
 * through config_apply_text, the path config_load takes after reading the
 * file. A rejected file must say why and change nothing; an accepted one
 * must leave every parameter in range and the set valid. */
#include <cjson/cJSON.h>
#include <sanitizer/asan_interface.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

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

/* 64-byte-vector comparison, left out of coverage tracing and ASan checks:
 * the structs are ours and aligned, and libFuzzer's memcmp hook or a checked
 * byte loop over these ~7 KiB structs (the daemon_config's path buffers)
 * cost more than the code under test; a word loop at -O1 still took 7 % of
 * an execution (perf), the vector one a fraction of that. */
typedef uint64_t v8u64 __attribute__((vector_size(64), aligned(8)));
__attribute__((no_sanitize("coverage", "address", "undefined"))) static int same_bytes(const void *a, const void *b, size_t n)
{
    const unsigned char *x = a, *y = b;
    v8u64 d = {0};
    size_t i = 0;
    for (; i + 64 <= n; i += 64) {
        v8u64 u, v;
        memcpy(&u, x + i, 64);
        memcpy(&v, y + i, 64);
        d |= u ^ v;
    }
    uint64_t acc = 0;
    for (int k = 0; k < 8; k++)
        acc |= d[k];
    for (; i < n; i++)
        acc |= (uint64_t)(x[i] ^ y[i]);
    return acc == 0;
}

/* cJSON's nodes come from an arena reset after each input instead of the
 * ASan allocator (about a fifth of the time went to malloc/free and their
 * hooks). Each block keeps ASan's protection: it sits between poisoned zones
 * (a size header before, a red zone after: overflows are caught) and is
 * poisoned when freed (use after free is caught until the next input).
 * Falls back to malloc when the arena is full. */
#define ARENA_BYTES (8u << 20)
#define ZONE 32u /* header before a block, red zone after it */
static unsigned char arena[ARENA_BYTES] __attribute__((aligned(32)));
static size_t arena_used;

/* Reads and writes the (poisoned) size headers: not instrumented. */
__attribute__((no_sanitize("address", "coverage"))) static void *arena_malloc(size_t n)
{
    size_t need = ZONE + ((n + ZONE - 1) & ~(size_t)(ZONE - 1)) + ZONE;
    if (n > ARENA_BYTES || arena_used + need > ARENA_BYTES)
        return malloc(n);
    unsigned char *h = arena + arena_used, *p = h + ZONE;
    arena_used += need;
    *(size_t *)h = n;
    ASAN_UNPOISON_MEMORY_REGION(p, n);
    return p;
}

__attribute__((no_sanitize("address", "coverage"))) static void arena_free(void *ptr)
{
    unsigned char *p = ptr;
    if (p >= arena && p < arena + ARENA_BYTES) {
        ASAN_POISON_MEMORY_REGION(p, *(size_t *)(p - ZONE));
        return;
    }
    free(ptr);
}

__attribute__((no_sanitize("coverage"))) static void arena_reset(void)
{
    ASAN_POISON_MEMORY_REGION(arena, arena_used);
    arena_used = 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* dc and p are kept between inputs: a refused input must leave them as
     * they are (checked below), an accepted one is undone after its checks. */
    static struct daemon_config dc;
    static struct ocean_params p;
    static int ready;
    if (!ready) {
        load_defaults();
        dc = base_dc;
        p = base_p;
        ASAN_POISON_MEMORY_REGION(arena, sizeof arena);
        cJSON_Hooks hooks = { arena_malloc, arena_free };
        cJSON_InitHooks(&hooks);
        ready = 1;
    }
    arena_reset();
    char err[512];
    err[0] = '\0';
    if (config_apply_text(&dc, &p, (const char *)data, size, err, sizeof err) == 0) {
        for (size_t i = 0; i < param_count; i++) {
            double v = param_get(&p, &param_table[i]);
            if (!(v >= param_table[i].min && v <= param_table[i].max))
                abort();
        }
        if (params_validate(&p, err, sizeof err) != 0)
            abort();
        dc = base_dc;
        p = base_p;
    } else if (err[0] == '\0' || !same_bytes(&dc, &base_dc, sizeof dc) || !same_bytes(&p, &base_p, sizeof p)) {
        abort(); /* an error must say why and leave everything as it was */
    }
    return 0;
}

/* check.h — the check harness of the C test suites (one translation unit
 * each: everything here is static).
 *
 *   CHECK(cond, fmt, ...)   count a pass or a failure; a failure prints
 *                           "FAIL file:line: [section] message" on stdout
 *   check_verbose = 1       passes print "ok   message" too: for suites whose
 *                           passing lines carry the measured values
 *   check_section = "name"  prefix of the failure lines that follow (tests
 *                           whose checks sit in shared helpers)
 *   return check_done();    prints the closing line "N passed, N failed",
 *                           alone on its line (CI reads it); returns the exit
 *                           status, 1 on any failure
 *   check_quick()           OCEAN_TEST_QUICK is set and not "0": the reduced
 *                           run (smaller N, fewer seeds) valgrind and TSan get
 *
 * Everything goes to stdout, flushed per line, so that a crash or a sanitizer
 * report lands after the last check it followed. */
#ifndef OCEAND_TESTS_CHECK_H
#define OCEAND_TESTS_CHECK_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int check_passed, check_failed;
static int check_verbose;
static const char *check_section;

__attribute__((format(printf, 4, 5), unused))
static void check_report(int ok, const char *file, int line, const char *fmt, ...)
{
    if (ok) {
        check_passed++;
        if (!check_verbose)
            return;
        printf("ok   ");
    } else {
        check_failed++;
        printf("FAIL %s:%d: ", file, line);
    }
    if (check_section)
        printf("[%s] ", check_section);
    va_list ap;
    va_start(ap, fmt);
    vprintf(fmt, ap);
    va_end(ap);
    putchar('\n');
    fflush(stdout);
}

#define CHECK(cond, ...) check_report(!!(cond), __FILE__, __LINE__, __VA_ARGS__)

__attribute__((unused))
static int check_done(void)
{
    printf("%d passed, %d failed\n", check_passed, check_failed);
    fflush(stdout);
    return check_failed ? 1 : 0;
}

__attribute__((unused))
static int check_quick(void)
{
    const char *q = getenv("OCEAN_TEST_QUICK");
    return q && *q && strcmp(q, "0") != 0;
}

#endif

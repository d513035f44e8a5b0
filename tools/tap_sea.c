/* tap_sea.c — `ocean-tap sea SOURCE`: a measured sea (placeholder until the readers land). */
#include <stdio.h>

#include "tap.h"

int tap_sea_main(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "ocean-tap: sea: not built yet\n");
    return EXIT_USAGE;
}

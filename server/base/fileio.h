/* fileio.h — whole-file reads for the config and state files. */
#ifndef OCEAND_FILEIO_H
#define OCEAND_FILEIO_H

#include <stddef.h>

/* Read a whole regular file of at most max bytes into a malloc'd,
 * NUL-terminated *text (free()). Returns 0; -1 with a message in err (errno
 * kept: ENOENT for a missing file; a larger file is refused, never cut);
 * -2 when path is not a regular file (a FIFO, directory, device), refused
 * at once without reading or blocking. Used for the config and state files. */
int file_read_all(const char *path, size_t max, char **text, size_t *len, char *err, size_t errlen);

#endif

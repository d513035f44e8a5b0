/* fileio.c — reading a whole configuration-sized file, with the checks a
 * daemon needs before it trusts one (size cap, regular file, no blocking). */
#include "fileio.h"

#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* Hand-written: none of the libraries we link reads a file (cJSON parses
 * text only), and the checks below are the point. */
int file_read_all(const char *path, size_t max, char **text, size_t *len, char *err, size_t errlen)
{
    /* O_NONBLOCK: opening a FIFO for reading would otherwise wait for a
     * writer forever; for a regular file the flag changes nothing. */
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
    if (fd < 0) {
        int e = errno;
        snprintf(err, errlen, "%s: %s", path, strerror(e));
        errno = e;
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) != 0) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    if (!S_ISREG(st.st_mode)) {
        const char *kind = S_ISFIFO(st.st_mode) ? "a FIFO" : S_ISDIR(st.st_mode) ? "a directory"
                         : S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ? "a device"
                         : S_ISSOCK(st.st_mode) ? "a socket" : "not a plain file";
        snprintf(err, errlen, "%s: not a regular file (%s)", path, kind);
        close(fd);
        return -2;
    }
    if ((uintmax_t)st.st_size > max) {
        snprintf(err, errlen, "%s: %jd bytes, more than the %zu bytes (%zu MiB) allowed; refusing it",
                 path, (intmax_t)st.st_size, max, max >> 20);
        close(fd);
        return -1;
    }
    /* One byte more than the size, to see a file that grew meanwhile. */
    size_t cap = (size_t)st.st_size + 1, n = 0;
    char *buf = malloc(cap + 1);
    if (!buf) {
        snprintf(err, errlen, "%s: out of memory", path);
        close(fd);
        return -1;
    }
    for (;;) {
        ssize_t r = read(fd, buf + n, cap - n);
        if (r < 0 && errno == EINTR)
            continue;
        if (r < 0) {
            snprintf(err, errlen, "%s: %s", path, strerror(errno));
            free(buf);
            close(fd);
            return -1;
        }
        if (r == 0)
            break;
        n += (size_t)r;
        if (n == cap) {
            if (n > max) {
                snprintf(err, errlen, "%s: more than the %zu bytes allowed (it grew while read); refusing it", path, max);
                free(buf);
                close(fd);
                return -1;
            }
            char *nb = realloc(buf, 2 * cap + 1);
            if (!nb) {
                snprintf(err, errlen, "%s: out of memory", path);
                free(buf);
                close(fd);
                return -1;
            }
            buf = nb;
            cap *= 2;
        }
    }
    close(fd);
    buf[n] = '\0';
    *text = buf;
    *len = n;
    return 0;
}

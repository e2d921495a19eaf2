/*
 * bg_file — the file helpers every library needs: mkdir -p, and a whole
 * file read into memory under a cap (so a huge or endless file such as
 * /dev/zero is refused, never allocated).
 */
#ifndef BG_FILE_H
#define BG_FILE_H

#include <stddef.h>

#include "bg_error.h"

/*
 * mkdir -p: creates path and its missing parents (mode 0755). Returns 0,
 * or −1 with errno set (ENAMETOOLONG for a path of 4096 bytes or more,
 * ENOTDIR when path exists and is not a directory).
 */
int bg_file_make_directories(const char *path);

/*
 * Reads a whole file into a NUL-terminated buffer of at most max_bytes.
 * Caller frees *text. Messages name the path and the OS error; a file
 * over the cap is BG_ERR_LIMIT, an unreadable one BG_ERR_IO.
 */
bg_status bg_file_read_all(const char *path, size_t max_bytes, char **text, size_t *length,
                           bg_error_t *err);

#endif

/*
 * bg_file — the file helpers every library needs: mkdir -p, a whole file
 * read into memory under a cap (so a huge or endless file such as
 * /dev/zero is refused, never allocated), and the lookup of a file a
 * scene names.
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

/* bg_file_make_directories with the folders it creates given `mode`
 * (0700 for a folder only its owner may read), in the status idiom:
 * BG_ERR_IO naming the path and the OS error. */
bg_status bg_file_make_directories_mode(const char *path, unsigned mode, bg_error_t *err);

/*
 * Writes size bytes to path whole or not at all: into path.part (created
 * with `mode`, e.g. 0600), then renamed over path, so a reader never sees
 * half a file. BG_ERR_IO naming the path and the OS error.
 */
bg_status bg_file_write_all(const char *path, const void *data, size_t size, unsigned mode,
                            bg_error_t *err);

/*
 * dir + "/" + name into buf (size bytes, NUL included): the one way every
 * library and the command build a path inside a folder. Returns 0, or −1
 * when it does not fit (buf is then left unterminated garbage: callers
 * report "name too long" and do not use it).
 */
int bg_file_join(char *buf, size_t size, const char *dir, const char *name);

/*
 * Reads a whole file into a NUL-terminated buffer of at most max_bytes.
 * Caller frees *text. Messages name the path and the OS error; a file
 * over the cap is BG_ERR_LIMIT, an unreadable one BG_ERR_IO.
 */
bg_status bg_file_read_all(const char *path, size_t max_bytes, char **text, size_t *length,
                           bg_error_t *err);

/*
 * The canonical absolute path of an existing file or folder (symbolic
 * links, "." and ".." resolved: ./x, x and /abs/x name one place) into
 * out[size]. Returns 0, or −1 with errno set (ENOENT when path does not
 * exist, ENAMETOOLONG when the result does not fit).
 */
int bg_file_canonical(const char *path, char *out, size_t size);

/* bg_file_lookup flags. */
#define BG_FILE_REGULAR 1u        /* found = a regular file (else anything but a directory) */
#define BG_FILE_TRUST_ABSOLUTE 2u /* an absolute name is found as given, unchecked */

/*
 * Where a file a scene names is, the rule `solve` and `submit` share: an
 * absolute name as given; a relative one beside the scene (dir + name; dir
 * is "" or ends with '/'), else by its last component in each folder of
 * the ':'-separated search_path (NULL: none), in order. The scene parser
 * trusts an absolute name and accepts any non-directory (a FIFO or device
 * fails later in the reader, with its own message); the client uploads
 * only what it can read whole, so it asks for a regular file. Found: BG_OK
 * and *found (caller frees). Not found: BG_ERR_NOT_FOUND, *found NULL,
 * *tried = the path beside the scene (caller frees) and *why = what was
 * wrong with it ("No such file or directory", "a directory", "not a
 * regular file"; valid until the next strerror), for the caller's message
 * (it names the field). BG_ERR_NOMEM: *found and *tried NULL.
 */
bg_status bg_file_lookup(const char *dir, const char *name, const char *search_path, unsigned flags,
                         char **found, char **tried, const char **why);

#endif

/* realpath is XSI: ask for it here rather than widen the whole build. */
#define _XOPEN_SOURCE 700

#include "bg_file.h"

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <fcntl.h>
#include <sys/types.h>
#include <unistd.h>

/* Initial buffer for reading a file whose size stat cannot tell. */
#define READ_CHUNK_BYTES ((size_t)1 << 16)
#define PATH_BYTES 4096

/* mkdir -p with `mode`; 0 or −1 with errno. */
static int make_directories(const char *path, unsigned mode)
{
    char buf[PATH_BYTES];
    size_t len = path ? strlen(path) : 0;
    if (len == 0 || len >= sizeof buf) {
        errno = len == 0 ? ENOENT : ENAMETOOLONG;
        return -1;
    }
    memcpy(buf, path, len + 1);
    for (size_t i = 1; i <= len; i++) {
        if (buf[i] == '/' || buf[i] == '\0') {
            char saved = buf[i];
            buf[i] = '\0';
            if (mkdir(buf, (mode_t)mode) != 0 && errno != EEXIST)
                return -1;
            buf[i] = saved;
        }
    }
    struct stat st;
    if (stat(path, &st) != 0)
        return -1;
    if (!S_ISDIR(st.st_mode)) {
        errno = ENOTDIR;
        return -1;
    }
    return 0;
}

int bg_file_make_directories(const char *path)
{
    return make_directories(path, 0755);
}

bg_status bg_file_make_directories_mode(const char *path, unsigned mode, bg_error_t *err)
{
    if (make_directories(path, mode) != 0)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot create the folder: %s",
                            path ? path : "(null)", strerror(errno));
    return BG_OK;
}

int bg_file_join(char *buf, size_t size, const char *dir, const char *name)
{
    const size_t a = strlen(dir), b = strlen(name);
    if (a + 1 + b + 1 > size)
        return -1;
    memcpy(buf, dir, a);
    buf[a] = '/';
    memcpy(buf + a + 1, name, b + 1);
    return 0;
}

bg_status bg_file_read_all(const char *path, size_t max_bytes, char **text, size_t *length,
                           bg_error_t *err)
{
    FILE *f = NULL;
    char *buf = NULL;
    size_t n = 0, cap = READ_CHUNK_BYTES;
    struct stat info;
    bg_status st = BG_OK;
    *text = NULL;
    *length = 0;
    if (!path)
        return bg_error_set(err, BG_ERR_INVALID, "bg_file_read_all: NULL path");
    /* Keeps max_bytes + 1 (the NUL) and the doubling below from overflowing. */
    if (max_bytes > SIZE_MAX / 4)
        max_bytes = SIZE_MAX / 4;
    f = fopen(path, "rb");
    if (!f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    if (fstat(fileno(f), &info) == 0) {
        if (S_ISDIR(info.st_mode)) {
            st = bg_error_set(err, BG_ERR_IO, "%s: is a directory", path);
            goto out;
        }
        /* A regular file's size is known: refuse early, allocate once. */
        if (S_ISREG(info.st_mode)) {
            if ((uint64_t)info.st_size > (uint64_t)max_bytes) {
                st = bg_error_set(err, BG_ERR_LIMIT, "%s: %lld bytes exceed the limit of %zu bytes",
                                  path, (long long)info.st_size, max_bytes);
                goto out;
            }
            cap = (size_t)info.st_size + 1;
        }
    }
    if (cap > max_bytes + 1)
        cap = max_bytes + 1;
    buf = malloc(cap);
    if (!buf) {
        st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory reading %zu bytes", path, cap);
        goto out;
    }
    for (;;) {
        if (n == cap - 1) {
            /* Full: only grow when there is more to read. */
            int c = fgetc(f);
            if (c == EOF)
                break;
            if (n >= max_bytes) {
                st = bg_error_set(err, BG_ERR_LIMIT, "%s: longer than the limit of %zu bytes", path,
                                  max_bytes);
                goto out;
            }
            size_t grown = cap > (max_bytes + 1) / 2 ? max_bytes + 1 : 2 * cap;
            char *p = realloc(buf, grown);
            if (!p) {
                st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory reading %zu bytes", path,
                                  grown);
                goto out;
            }
            buf = p;
            cap = grown;
            buf[n++] = (char)c;
        }
        size_t got = fread(buf + n, 1, cap - 1 - n, f);
        n += got;
        if (got == 0 && n < cap - 1)
            break;
    }
    if (ferror(f)) {
        st = bg_error_set(err, BG_ERR_IO, "%s: read failed: %s", path, strerror(errno));
        goto out;
    }
    buf[n] = '\0';
    *text = buf;
    *length = n;
    buf = NULL;
out:
    free(buf);
    fclose(f);
    return st;
}

/* Why a path is not a hit, beside errno values. */
#define LOOKUP_DIRECTORY (-1)
#define LOOKUP_NOT_REGULAR (-2)

/* Whether path counts as found: a regular file, or anything but a
 * directory; if not, *why is an errno or one of the LOOKUP_ codes. */
static int lookup_hit(const char *path, unsigned flags, int *why)
{
    struct stat sb;
    if (stat(path, &sb) != 0) {
        *why = errno;
        return 0;
    }
    *why = S_ISDIR(sb.st_mode)                                 ? LOOKUP_DIRECTORY
           : (flags & BG_FILE_REGULAR) && !S_ISREG(sb.st_mode) ? LOOKUP_NOT_REGULAR
                                                               : 0;
    return *why == 0;
}

bg_status bg_file_lookup(const char *dir, const char *name, const char *search_path, unsigned flags,
                         char **found, char **tried, const char **why)
{
    *found = NULL;
    *tried = NULL;
    *why = "";
    const int absolute = name[0] == '/';
    const char *base = absolute ? "" : dir;
    const size_t n = strlen(base) + strlen(name) + 1;
    char *beside = malloc(n);
    if (!beside)
        return BG_ERR_NOMEM;
    snprintf(beside, n, "%s%s", base, name);
    int why_beside = 0;
    if ((absolute && (flags & BG_FILE_TRUST_ABSOLUTE)) || lookup_hit(beside, flags, &why_beside)) {
        *found = beside;
        return BG_OK;
    }
    const char *slash = strrchr(name, '/');
    const char *last = slash ? slash + 1 : name;
    for (const char *f = search_path ? search_path : ""; *f && !absolute && last[0];) {
        size_t length = strcspn(f, ":");
        const char *folder = f;
        f += length;
        if (*f == ':')
            f++;
        while (length > 1 && folder[length - 1] == '/')
            length--;
        if (length == 0)
            continue;
        const size_t m = length + 1 + strlen(last) + 1;
        char *candidate = malloc(m);
        if (!candidate) {
            free(beside);
            return BG_ERR_NOMEM;
        }
        snprintf(candidate, m, "%.*s/%s", (int)length, folder, last);
        int ignored = 0;
        if (lookup_hit(candidate, flags, &ignored)) {
            free(beside);
            *found = candidate;
            return BG_OK;
        }
        free(candidate);
    }
    *tried = beside;
    *why = why_beside == LOOKUP_DIRECTORY     ? "a directory"
           : why_beside == LOOKUP_NOT_REGULAR ? "not a regular file"
                                              : strerror(why_beside ? why_beside : ENOENT);
    return BG_ERR_NOT_FOUND;
}

int bg_file_canonical(const char *path, char *out, size_t size)
{
    char real[PATH_BYTES];
    if (!path || !realpath(path, real))
        return -1;
    const size_t n = strlen(real);
    if (n + 1 > size) {
        errno = ENAMETOOLONG;
        return -1;
    }
    memcpy(out, real, n + 1);
    return 0;
}

bg_status bg_file_write_all(const char *path, const void *data, size_t size, unsigned mode,
                            bg_error_t *err)
{
    char temp[PATH_BYTES + 16];
    if (!path || snprintf(temp, sizeof temp, "%s.part", path) >= (int)sizeof temp)
        return bg_error_set(err, BG_ERR_INVALID, "%s: path too long", path ? path : "(null)");
    const int fd = open(temp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, (mode_t)mode);
    if (fd < 0)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    const uint8_t *p = data;
    size_t done = 0;
    while (done < size) {
        const ssize_t n = write(fd, p + done, size - done);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            const int e = errno;
            close(fd);
            unlink(temp);
            return bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", path, strerror(e));
        }
        done += (size_t)n;
    }
    if (close(fd) != 0 || rename(temp, path) != 0) {
        const int e = errno;
        unlink(temp);
        return bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", path, strerror(e));
    }
    return BG_OK;
}

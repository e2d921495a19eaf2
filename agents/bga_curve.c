#include "bga_curve.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zmq.h>

static const char Z85_ALPHABET[] = "0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                                   ".-:+=^!/*?&<>()[]{}@%$#";

/* Secrets do not linger in buffers the process frees or reuses. */
static void wipe(void *p, size_t n)
{
    volatile unsigned char *v = p;
    while (n--)
        *v++ = 0;
}

int bga_curve_available(void)
{
    return zmq_has("curve") != 0;
}

int bga_curve_key_valid(const char *s)
{
    if (!s || strlen(s) != BGA_CURVE_KEY_LEN)
        return 0;
    for (const char *p = s; *p; p++)
        if (!strchr(Z85_ALPHABET, *p))
            return 0;
    return 1;
}

int bga_curve_name_valid(const char *name)
{
    const size_t n = name ? strlen(name) : 0;
    if (n == 0 || n >= BGA_CURVE_NAME_MAX || name[0] == '.')
        return 0;
    return strspn(name, "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_.") == n;
}

bg_status bga_curve_generate(bga_curve_keypair_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    if (!bga_curve_available())
        return bg_error_set(err, BG_ERR_UNSUPPORTED,
                            "this libzmq was built without CURVE (zmq_has(\"curve\") is 0)");
    if (zmq_curve_keypair(out->public_key, out->secret_key) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot make a CURVE key pair: %s",
                            zmq_strerror(zmq_errno()));
    return BG_OK;
}

/* The text between p and end without spaces, tabs and a CR at either end. */
static void trim(const char **p, const char **end)
{
    while (*p < *end && (**p == ' ' || **p == '\t'))
        (*p)++;
    while (*end > *p && ((*end)[-1] == ' ' || (*end)[-1] == '\t' || (*end)[-1] == '\r'))
        (*end)--;
}

/* Whether [p, end) is 40 Z85 characters. */
static int key_line(const char *p, const char *end)
{
    if (end - p != BGA_CURVE_KEY_LEN)
        return 0;
    for (; p < end; p++)
        if (!*p || !strchr(Z85_ALPHABET, *p))
            return 0;
    return 1;
}

bg_status bga_curve_parse(const char *text, size_t length, const char *where,
                          char key[BGA_CURVE_KEY_SIZE], int *secret, bg_error_t *err)
{
    key[0] = '\0';
    if (secret)
        *secret = 0;
    int line = 0, key_at = 0;
    const char *p = text, *stop = text + length;
    while (p < stop) {
        const char *nl = memchr(p, '\n', (size_t)(stop - p));
        const char *end = nl ? nl : stop;
        const char *a = p, *b = end;
        line++;
        trim(&a, &b);
        /* A key line first: '#' is a Z85 character, so a key may start with it. */
        if (key_line(a, b)) {
            if (key_at)
                return bg_error_set(err, BG_ERR_INVALID,
                                    "%s:%d: a second key (the first is on line %d): a key file "
                                    "holds one",
                                    where, line, key_at);
            memcpy(key, a, BGA_CURVE_KEY_LEN);
            key[BGA_CURVE_KEY_LEN] = '\0';
            key_at = line;
        } else if (a < b && *a == '#') {
            if (secret && (size_t)(b - a) == strlen(BGA_CURVE_SECRET_MARK) &&
                memcmp(a, BGA_CURVE_SECRET_MARK, (size_t)(b - a)) == 0)
                *secret = 1;
        } else if (a < b) {
            key[0] = '\0';
            return bg_error_set(err, BG_ERR_INVALID,
                                "%s:%d: not a CURVE key: a key is one line of %d Z85 characters "
                                "(this one has %d characters%s)",
                                where, line, BGA_CURVE_KEY_LEN, (int)(b - a),
                                memchr(a, '\0', (size_t)(b - a)) ? ", a NUL among them" : "");
        }
        p = nl ? nl + 1 : stop;
    }
    if (!key_at)
        return bg_error_set(err, BG_ERR_INVALID, "%s: no key in it (a line of %d Z85 characters)",
                            where, BGA_CURVE_KEY_LEN);
    return BG_OK;
}

/* Reads a key file whole (at most BGA_CURVE_FILE_MAX bytes) into buf;
 * *mode gets its permission bits. */
static bg_status read_key_file(const char *path, char *buf, size_t *length, unsigned *mode,
                               bg_error_t *err)
{
    const int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    struct stat st;
    bg_status status = BG_OK;
    if (fstat(fd, &st) != 0) {
        status = bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    } else if (!S_ISREG(st.st_mode)) {
        status = bg_error_set(err, BG_ERR_INVALID, "%s: not a regular file", path);
    } else {
        *mode = (unsigned)(st.st_mode & 07777);
        size_t n = 0;
        for (;;) {
            const ssize_t r = read(fd, buf + n, BGA_CURVE_FILE_MAX + 1 - n);
            if (r < 0 && errno == EINTR)
                continue;
            if (r < 0) {
                status = bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
                break;
            }
            if (r == 0)
                break;
            n += (size_t)r;
            if (n > BGA_CURVE_FILE_MAX) {
                status =
                    bg_error_set(err, BG_ERR_INVALID, "%s: longer than %d bytes: not a key file",
                                 path, BGA_CURVE_FILE_MAX);
                break;
            }
        }
        *length = n;
    }
    close(fd);
    return status;
}

bg_status bga_curve_read_secret(const char *path, bga_curve_keypair_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    char buf[BGA_CURVE_FILE_MAX + 1];
    size_t length = 0;
    unsigned mode = 0;
    bg_status st = read_key_file(path, buf, &length, &mode, err);
    if (st == BG_OK && (mode & 077))
        st = bg_error_set(err, BG_ERR_INVALID,
                          "%s: mode %04o lets group or others read a secret key: chmod 600 %s",
                          path, mode, path);
    if (st == BG_OK)
        st = bga_curve_parse(buf, length, path, out->secret_key, NULL, err);
    if (st == BG_OK && !bga_curve_available())
        st = bg_error_set(err, BG_ERR_UNSUPPORTED,
                          "this libzmq was built without CURVE (zmq_has(\"curve\") is 0)");
    if (st == BG_OK && zmq_curve_public(out->public_key, out->secret_key) != 0)
        st = bg_error_set(err, BG_ERR_INVALID, "%s: not a CURVE secret key", path);
    wipe(buf, sizeof buf);
    if (st != BG_OK)
        wipe(out, sizeof *out);
    return st;
}

bg_status bga_curve_read_public(const char *path, char key[BGA_CURVE_KEY_SIZE], bg_error_t *err)
{
    key[0] = '\0';
    char buf[BGA_CURVE_FILE_MAX + 1];
    size_t length = 0;
    unsigned mode = 0;
    int secret = 0;
    bg_status st = read_key_file(path, buf, &length, &mode, err);
    if (st == BG_OK)
        st = bga_curve_parse(buf, length, path, key, &secret, err);
    if (st == BG_OK && secret) {
        key[0] = '\0';
        st = bg_error_set(err, BG_ERR_INVALID,
                          "%s is a secret key file: give its public key (the %s file beside it)",
                          path, BGA_CURVE_PUBLIC_SUFFIX);
    }
    wipe(buf, sizeof buf);
    return st;
}

bg_status bga_curve_name_of(const char *path, const char *suffix, char name[BGA_CURVE_NAME_MAX],
                            bg_error_t *err)
{
    name[0] = '\0';
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    const size_t n = strlen(base), s = strlen(suffix);
    if (n <= s || strcmp(base + n - s, suffix) != 0)
        return bg_error_set(err, BG_ERR_INVALID, "%s: a key file's name ends with %s", path,
                            suffix);
    if (n - s >= BGA_CURVE_NAME_MAX)
        return bg_error_set(err, BG_ERR_INVALID, "%s: the key's name is longer than %d characters",
                            path, BGA_CURVE_NAME_MAX - 1);
    memcpy(name, base, n - s);
    name[n - s] = '\0';
    if (!bga_curve_name_valid(name)) {
        const bg_status st = bg_error_set(err, BG_ERR_INVALID,
                                          "%s: the key's name '%s' must be letters, digits, '-', "
                                          "'_' or '.' (not first)",
                                          path, name);
        name[0] = '\0';
        return st;
    }
    return BG_OK;
}

/* Writes text to a new file at path, which must not exist: into a private
 * name beside it, then hard-linked into place (link never replaces). */
static bg_status write_new(const char *path, const char *text, unsigned mode, bg_error_t *err)
{
    char tmp[PATH_MAX];
    if (snprintf(tmp, sizeof tmp, "%s.%ld.part", path, (long)getpid()) >= (int)sizeof tmp)
        return bg_error_set(err, BG_ERR_INVALID, "%s: path too long", path);
    unlink(tmp);
    const int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, (mode_t)mode);
    if (fd < 0)
        return bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    bg_status st = BG_OK;
    const size_t n = strlen(text);
    size_t done = 0;
    /* The mode asked, whatever the umask. */
    if (fchmod(fd, (mode_t)mode) != 0)
        st = bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    while (st == BG_OK && done < n) {
        const ssize_t w = write(fd, text + done, n - done);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0)
            st = bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
        else
            done += (size_t)w;
    }
    if (st == BG_OK && fsync(fd) != 0)
        st = bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    if (close(fd) != 0 && st == BG_OK)
        st = bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    if (st == BG_OK && link(tmp, path) != 0)
        st = errno == EEXIST
                 ? bg_error_set(err, BG_ERR_CONFLICT, "%s exists: a key is never overwritten", path)
                 : bg_error_set(err, BG_ERR_IO, "%s: %s", path, strerror(errno));
    unlink(tmp);
    return st;
}

bg_status bga_curve_write(const char *prefix, const bga_curve_keypair_t *pair, bg_error_t *err)
{
    if (!bga_curve_key_valid(pair->public_key) || !bga_curve_key_valid(pair->secret_key))
        return bg_error_set(err, BG_ERR_INVALID, "not a CURVE key pair");
    char pub[PATH_MAX], sec[PATH_MAX];
    if (snprintf(pub, sizeof pub, "%s%s", prefix, BGA_CURVE_PUBLIC_SUFFIX) >= (int)sizeof pub ||
        snprintf(sec, sizeof sec, "%s%s", prefix, BGA_CURVE_SECRET_SUFFIX) >= (int)sizeof sec)
        return bg_error_set(err, BG_ERR_INVALID, "%s: path too long", prefix);
    struct stat st;
    if (lstat(sec, &st) == 0 || lstat(pub, &st) == 0)
        return bg_error_set(err, BG_ERR_CONFLICT, "%s exists: a key is never overwritten",
                            lstat(sec, &st) == 0 ? sec : pub);
    char text[sizeof BGA_CURVE_SECRET_MARK + BGA_CURVE_KEY_SIZE + 2];
    snprintf(text, sizeof text, "%s\n%s\n", BGA_CURVE_SECRET_MARK, pair->secret_key);
    bg_status status = write_new(sec, text, 0600, err);
    wipe(text, sizeof text);
    if (status != BG_OK)
        return status;
    char line[BGA_CURVE_KEY_SIZE + 1];
    snprintf(line, sizeof line, "%s\n", pair->public_key);
    if ((status = write_new(pub, line, 0644, err)) != BG_OK)
        unlink(sec);
    return status;
}

/* The host of a tcp:// endpoint into host[size] (brackets of an IPv6
 * literal removed); 0 when there is none. */
static int tcp_host(const char *endpoint, char *host, size_t size)
{
    if (strncmp(endpoint, "tcp://", 6) != 0)
        return 0;
    const char *h = endpoint + 6;
    const char *colon = strrchr(h, ':');
    if (!colon || colon == h)
        return 0;
    size_t n = (size_t)(colon - h);
    if (h[0] == '[' && n >= 2 && h[n - 1] == ']') {
        h++;
        n -= 2;
    }
    if (n == 0 || n >= size)
        return 0;
    memcpy(host, h, n);
    host[n] = '\0';
    return 1;
}

int bga_curve_endpoint_is_loopback(const char *endpoint)
{
    if (!endpoint)
        return 0;
    if (strncmp(endpoint, "ipc://", 6) == 0 || strncmp(endpoint, "inproc://", 9) == 0)
        return 1;
    char host[256];
    if (!tcp_host(endpoint, host, sizeof host) || strchr(host, ';'))
        return 0;
    if (strcmp(host, "localhost") == 0 || strcmp(host, "lo") == 0)
        return 1;
    unsigned char addr[16];
    if (inet_pton(AF_INET, host, addr) == 1)
        return addr[0] == 127;
    if (inet_pton(AF_INET6, host, addr) == 1) {
        static const unsigned char loop6[16] = {[15] = 1};
        return memcmp(addr, loop6, sizeof loop6) == 0;
    }
    return 0;
}

static bg_status set_option(void *socket, int option, const void *value, size_t size,
                            const char *name, bg_error_t *err)
{
    if (zmq_setsockopt(socket, option, value, size) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot set %s: %s", name, zmq_strerror(zmq_errno()));
    return BG_OK;
}

bg_status bga_curve_server(void *socket, const bga_curve_keypair_t *pair, bg_error_t *err)
{
    const int on = 1;
    bg_status st = set_option(socket, ZMQ_CURVE_SERVER, &on, sizeof on, "ZMQ_CURVE_SERVER", err);
    if (st == BG_OK)
        st = set_option(socket, ZMQ_CURVE_SECRETKEY, pair->secret_key, BGA_CURVE_KEY_LEN,
                        "ZMQ_CURVE_SECRETKEY", err);
    if (st == BG_OK)
        st = set_option(socket, ZMQ_ZAP_DOMAIN, BGA_CURVE_DOMAIN, strlen(BGA_CURVE_DOMAIN),
                        "ZMQ_ZAP_DOMAIN", err);
    return st;
}

bg_status bga_curve_client(void *socket, const bga_curve_keypair_t *pair, const char *server_key,
                           bg_error_t *err)
{
    if (!bga_curve_key_valid(server_key))
        return bg_error_set(err, BG_ERR_INVALID, "the server's CURVE key is not 40 Z85 characters");
    bg_status st = set_option(socket, ZMQ_CURVE_SERVERKEY, server_key, BGA_CURVE_KEY_LEN,
                              "ZMQ_CURVE_SERVERKEY", err);
    if (st == BG_OK)
        st = set_option(socket, ZMQ_CURVE_PUBLICKEY, pair->public_key, BGA_CURVE_KEY_LEN,
                        "ZMQ_CURVE_PUBLICKEY", err);
    if (st == BG_OK)
        st = set_option(socket, ZMQ_CURVE_SECRETKEY, pair->secret_key, BGA_CURVE_KEY_LEN,
                        "ZMQ_CURVE_SECRETKEY", err);
    return st;
}

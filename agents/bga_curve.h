/*
 * bga_curve — CURVE security for the grid's ZeroMQ sockets, on libzmq's own
 * CurveZMQ (Curve25519 keys written as Z85 text): key pairs and their
 * files, the socket options of a CURVE server and of a client, and whether
 * an endpoint stays on this machine.
 *
 * Files, as `biotgrid keygen PREFIX` writes them: PREFIX.pub holds the
 * public key, one Z85 line of 40 characters, to give to peers; PREFIX.key
 * holds the secret key (a comment line saying so, then its Z85 line), mode
 * 0600. A secret key file that group or others may read is refused, as ssh
 * refuses one; a public key read from a file marked secret is refused too
 * (a mix-up that would hand out the secret). Reading skips blank lines and
 * lines that start with '#'. A key's name is its file name without the
 * suffix: the broker's allowlist (a folder of NAME.pub files) binds an
 * agent's name to the key in its NAME.pub.
 *
 * Ownership: key pairs are plain values; nothing here allocates. The
 * socket helpers set options only: call them before bind or connect.
 */
#ifndef BGA_CURVE_H
#define BGA_CURVE_H

#include <stddef.h>

#include "bg_error.h"

#define BGA_CURVE_KEY_LEN 40  /* Z85 characters of a 32-byte key */
#define BGA_CURVE_KEY_SIZE 41 /* with its NUL */
#define BGA_CURVE_NAME_MAX 64 /* a key's name, NUL included (an agent's name's cap) */
#define BGA_CURVE_PUBLIC_SUFFIX ".pub"
#define BGA_CURVE_SECRET_SUFFIX ".key"
#define BGA_CURVE_FILE_MAX 4096 /* a longer file is not a key file */
/* The first line of a secret key file. */
#define BGA_CURVE_SECRET_MARK "# biotgrid CURVE secret key (Z85): keep it private"
/* The ZAP domain the grid's CURVE servers give (RFC 27). */
#define BGA_CURVE_DOMAIN "biotgrid"

typedef struct bga_curve_keypair {
    char public_key[BGA_CURVE_KEY_SIZE]; /* Z85 */
    char secret_key[BGA_CURVE_KEY_SIZE]; /* Z85 */
} bga_curve_keypair_t;

/* 1 when this libzmq was built with CURVE (zmq_has("curve")). */
int bga_curve_available(void);

/* A fresh key pair (zmq_curve_keypair). BG_ERR_UNSUPPORTED when libzmq
 * has no CURVE. */
bg_status bga_curve_generate(bga_curve_keypair_t *out, bg_error_t *err);

/*
 * Writes PREFIX.key (mode 0600) and PREFIX.pub (0644). Neither is ever
 * overwritten: an existing one is BG_ERR_CONFLICT naming it, and nothing
 * is written. Each file appears whole or not at all (written aside, then
 * linked into place); if the second cannot be written the first is
 * removed. BG_ERR_IO naming the path and the OS error.
 */
bg_status bga_curve_write(const char *prefix, const bga_curve_keypair_t *pair, bg_error_t *err);

/*
 * Reads a secret key file and derives its public key. BG_ERR_IO when it
 * cannot be read, BG_ERR_INVALID when group or others may read it (naming
 * the mode and the chmod that fixes it) or it is not a key file (naming
 * the file and the line).
 */
bg_status bga_curve_read_secret(const char *path, bga_curve_keypair_t *out, bg_error_t *err);

/* Reads a public key file (the Z85 line). BG_ERR_INVALID when it is
 * malformed or marked as a secret key; BG_ERR_IO when unreadable. */
bg_status bga_curve_read_public(const char *path, char key[BGA_CURVE_KEY_SIZE], bg_error_t *err);

/*
 * Pure: the one key line of a key file's text (length bytes), skipping
 * blank lines and '#' comments, into key. *secret (may be NULL) is 1 when
 * the text carries BGA_CURVE_SECRET_MARK. BG_ERR_INVALID naming `where`
 * and the line: no key, a second key, a line that is not 40 Z85
 * characters.
 */
bg_status bga_curve_parse(const char *text, size_t length, const char *where,
                          char key[BGA_CURVE_KEY_SIZE], int *secret, bg_error_t *err);

/* Whether s is exactly 40 characters of the Z85 alphabet. */
int bga_curve_key_valid(const char *s);

/* Whether name may name a key (and an agent): 1 to 63 letters, digits,
 * '-', '_' or '.', not starting with '.'. */
int bga_curve_name_valid(const char *name);

/* The name of a key file: its last path component without `suffix`
 * (".pub" or ".key"). BG_ERR_INVALID when the path does not end with the
 * suffix or the name is not valid (bga_curve_name_valid). */
bg_status bga_curve_name_of(const char *path, const char *suffix, char name[BGA_CURVE_NAME_MAX],
                            bg_error_t *err);

/*
 * Whether a ZeroMQ endpoint stays on this machine: tcp:// on a loopback
 * host (127.0.0.0/8, ::1, localhost, the interface lo), ipc:// and
 * inproc://. Anything else — a wildcard host ('*', 0.0.0.0), another
 * address, another transport — may be reached from the network.
 */
int bga_curve_endpoint_is_loopback(const char *endpoint);

/* Makes socket a CURVE server with this key pair (ZMQ_CURVE_SERVER,
 * ZMQ_CURVE_SECRETKEY, ZMQ_ZAP_DOMAIN BGA_CURVE_DOMAIN). Its context
 * needs a ZAP handler (bga_zap) before it binds: without one, libzmq
 * admits every client that knows the server's public key. */
bg_status bga_curve_server(void *socket, const bga_curve_keypair_t *pair, bg_error_t *err);

/* Makes socket a CURVE client with this key pair, expecting the server's
 * public key server_key (Z85). */
bg_status bga_curve_client(void *socket, const bga_curve_keypair_t *pair, const char *server_key,
                           bg_error_t *err);

/*
 * What a client needs to reach CURVE agents: its own key pair, and each
 * agent's public key by the agent's endpoint (the broker learns them as
 * agents register: bgb_loop). key_of writes the Z85 key, or returns
 * BG_ERR_NOT_FOUND with a message naming the endpoint. Borrowed by whoever
 * holds it; must outlive them.
 */
typedef struct bga_curve_peers {
    const bga_curve_keypair_t *self;
    bg_status (*key_of)(void *ctx, const char *endpoint, char key[BGA_CURVE_KEY_SIZE],
                        bg_error_t *err);
    void *ctx;
} bga_curve_peers_t;

#endif

/*
 * bga_zap — the gatekeeper of one ZeroMQ context's CURVE sockets: a thread
 * that answers their ZAP requests (ZeroMQ's authentication protocol, RFC
 * 27, version 1.0, on inproc://zeromq.zap.01) from an allowlist, and that
 * watches sockets' handshakes so every refused peer is logged with its
 * address and its key.
 *
 * The allowlist is a fixed list of named keys (an agent accepts only the
 * broker's), or a folder of NAME.pub files (bga_curve.h; the broker's
 * --authorized-agents, authorized_keys style). A folder is read whole and
 * strictly at bga_zap_new (a bad file, a key in two files: BG_ERR_INVALID
 * naming them), then read again before a request when it changed or a
 * second has passed, leniently (a bad file is logged and skipped): a key
 * added is accepted at its next connection, a key removed refused at its
 * next one (a connection already made stays until it closes).
 *
 * A listed key gets status 200 with the key's name as the user id, which
 * every message from that connection carries as its "User-Id" property
 * (zmq_msg_gets), and its Z85 text as the property BGA_ZAP_KEY_PROPERTY;
 * any other key, and any mechanism but CURVE, gets 400. Read them on a
 * message's body frames: libzmq 4.3's ROUTER drops them from the routing
 * frame of a message zmq_poll has already looked at.
 *
 * Refusals go to config.log, one line each (no trailing newline), e.g.
 *   "refused 10.77.3.13: CURVE key rq:rF… is not among the authorized
 *    agents' keys (2 in /srv/keys)"                      (a ZAP refusal)
 *   "agents' endpoint tcp://10.77.3.1:5570: refused 10.77.3.14:40212 (no
 *    key): no CURVE: it speaks another mechanism (plaintext)"  (watched)
 *   "broker tcp://10.77.3.1:5570: refused this process's CURVE key (ZAP
 *    status 400): ..."                                (a watched client)
 * The same refusal again within a minute is counted, not repeated (a
 * peer may retry ten times a second); the next line says how many.
 *
 * Threads: bga_zap_new, bga_zap_watch and bga_zap_destroy from the thread
 * that made it; the log callback runs on the handler's thread. Make it
 * before any CURVE server socket of the context binds (libzmq admits
 * every client of a context without a handler) and destroy it before
 * zmq_ctx_term, after the watched sockets are closed.
 */
#ifndef BGA_ZAP_H
#define BGA_ZAP_H

#include "bg_error.h"
#include "bga_curve.h"

/* The connection property holding the peer's CURVE key (Z85). */
#define BGA_ZAP_KEY_PROPERTY "X-Curve-Key"
/* Keys an allowlist holds at most; watched sockets per handler. */
#define BGA_ZAP_MAX_KEYS 4096
#define BGA_ZAP_MAX_WATCHES 8
/* Seconds within which one refusal is counted rather than logged again. */
#define BGA_ZAP_LOG_REPEAT 60.0

typedef struct bga_zap bga_zap_t;

typedef void (*bga_zap_log_fn)(void *ctx, const char *line);

typedef struct bga_zap_config {
    const char *folder;       /* the allowlist: every NAME.pub in it; NULL: the fixed list */
    const char *const *names; /* the fixed list: count keys (Z85) and their names */
    const char *const *keys;
    int count;
    /* Who the keys are, for refusal lines ("the broker's key"); NULL: "the authorized agents'
     * keys". */
    const char *whose;
    bga_zap_log_fn log; /* refusals and skipped files; NULL: none */
    void *log_ctx;
} bga_zap_config_t;

/* Reads the allowlist, binds the ZAP endpoint of zmq_ctx and starts the
 * handler's thread. BG_ERR_INVALID naming the folder or file when the
 * allowlist is bad; BG_ERR_IO when the context already has a handler.
 * Caller owns *out. */
bg_status bga_zap_new(void *zmq_ctx, const bga_zap_config_t *config, bga_zap_t **out,
                      bg_error_t *err);

/*
 * Watches socket's handshakes (zmq_socket_monitor) and logs its refusals,
 * as a server (server = 1: each peer refused for having no key or the
 * wrong server key, with its address; key refusals are the ZAP handler's
 * lines) or as a client (0: this process refused by the peer it connects
 * to). label names the socket in the lines ("agents' endpoint"). Call it
 * before the socket binds or connects, so no event is missed. Returns
 * once the handler listens.
 */
bg_status bga_zap_watch(bga_zap_t *zap, void *socket, const char *label, int server,
                        bg_error_t *err);

/* Reads a folder of NAME.pub files as bga_zap_new does (strictly) and
 * counts its keys, starting nothing: a daemon refuses a bad folder before
 * it makes any state. BG_ERR_INVALID naming the folder or the file. */
bg_status bga_zap_check_folder(const char *folder, int *count, bg_error_t *err);

/* Keys in the allowlist when it was made. */
int bga_zap_count(const bga_zap_t *zap);

/* Stops the thread, closes its sockets and frees; accepts NULL. */
void bga_zap_destroy(bga_zap_t **zap);

#endif

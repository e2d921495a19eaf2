/*
 * bgb_peers — who the agents on the broker's ZeroMQ endpoint are, and
 * which name and endpoint each may hold.
 *
 * A registration claims a name and a compute endpoint from a connection
 * (the ROUTER's routing id), with the peer's address and, over CURVE, the
 * key that authenticated the connection and that key's name (the ZAP
 * handler's user id, bga_zap). It is admitted when:
 *   - over CURVE, the name is its key's name: the broker's allowlist
 *     (NAME.pub) binds a name to one key, so no key takes another's name;
 *   - no other live connection holds the name, nor the endpoint: a second
 *     agent cannot take a registered name, nor point the coordinators at
 *     another agent's socket. A connection is live until it has been
 *     silent for `silence` seconds (the market's heartbeat timeout: the
 *     market has dropped it by then), so a restarted agent gets its name
 *     back once its old connection is gone.
 * The table also answers the coordinators: the key of the agent at an
 * endpoint (bgb_peers_key_of, the shape of bga_curve_peers_t.key_of), and
 * the views: an agent's address and key by name.
 *
 * Pure: no sockets, no clock (callers pass `now`). Threads: admit, seen
 * and lookup on the broker loop's thread; key_of from any thread (a mutex
 * guards the table).
 */
#ifndef BGB_PEERS_H
#define BGB_PEERS_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bga_curve.h"

/* Connections remembered at once (an agent daemon is one, for both its
 * roles), and the caps of what each holds. */
#define BGB_PEERS_MAX 1024
#define BGB_PEERS_CONNECTION_MAX 255
#define BGB_PEERS_NAME_MAX 64
#define BGB_PEERS_ENDPOINT_MAX 256
#define BGB_PEERS_ADDRESS_MAX 64
/* Seconds within which one connection's same refusal is not logged again. */
#define BGB_PEERS_LOG_REPEAT 60.0

typedef struct bgb_peers bgb_peers_t;

typedef struct bgb_peer_claim {
    const uint8_t *connection; /* the routing id */
    size_t connection_len;     /* 1 .. BGB_PEERS_CONNECTION_MAX */
    const char *name;          /* the registration's name */
    const char *endpoint;      /* its compute endpoint */
    const char *address;       /* the peer's IP address; NULL: unknown */
    const char *key_name;      /* over CURVE, the key's name (User-Id); NULL: plaintext */
    const char *key;           /* over CURVE, the key (Z85); NULL: plaintext */
} bgb_peer_claim_t;

/* curve: 1 when every claim must carry a key whose name is its own. */
bg_status bgb_peers_new(int curve, double silence, bgb_peers_t **out, bg_error_t *err);
void bgb_peers_destroy(bgb_peers_t **peers);

/*
 * Admits the claim (1: recorded, the connection now holds the name and
 * the endpoint) or refuses it (0): why[size] says why, naming the other
 * holder and its address, and *say is 1 when this refusal is news (the
 * first for this connection and reason, or BGB_PEERS_LOG_REPEAT seconds
 * after the last said), so the caller logs it once, not at every retry.
 */
int bgb_peers_admit(bgb_peers_t *peers, const bgb_peer_claim_t *claim, double now, char *why,
                    size_t size, int *say);

/* Any message from a connection keeps it live. */
void bgb_peers_seen(bgb_peers_t *peers, const uint8_t *connection, size_t connection_len,
                    double now);

/* The address (and, over CURVE, the key; "" in plaintext) recorded for
 * the agent called name: 1 when known. Either output may be NULL. */
int bgb_peers_lookup(bgb_peers_t *peers, const char *name, char *address, size_t size,
                     char key[BGA_CURVE_KEY_SIZE]);

/* The key of the agent registered with this compute endpoint (ctx is the
 * bgb_peers_t): BG_ERR_NOT_FOUND naming the endpoint when none is. Any
 * thread. */
bg_status bgb_peers_key_of(void *ctx, const char *endpoint, char key[BGA_CURVE_KEY_SIZE],
                           bg_error_t *err);

#endif

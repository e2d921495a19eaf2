/*
 * bgb_tokens — the bearer tokens of the REST API.
 *
 * A token is "bgt_<id>_<secret>": id, 16 hex digits, names the token's row
 * in the store; secret, 43 base64url characters, is 32 random bytes that
 * the store never sees: it keeps a random 16-byte salt and SHA-256(salt ‖
 * secret), and a presented token is checked by recomputing the hash and
 * comparing in constant time. A token belongs to a user (a name) and may
 * carry the admin scope. The token itself is shown once, when it is made.
 */
#ifndef BGB_TOKENS_H
#define BGB_TOKENS_H

#include <stddef.h>

#include "bg_error.h"
#include "bgb_store.h"

/* "bgt_" + 16 + "_" + 43 characters, and the NUL. */
#define BGB_TOKEN_SIZE 65
#define BGB_USER_MAX BGB_STORE_MAX_OWNER

/* Whether name is a user name: 1 to 64 of [A-Za-z0-9._-]. */
int bgb_tokens_valid_user(const char *name);

/*
 * Makes a new token for user (admin or not), stores its salted hash in
 * store, and writes the token to token[BGB_TOKEN_SIZE] (the only copy).
 * BG_ERR_INVALID for a bad user name, BG_ERR_IO when no random bytes.
 */
bg_status bgb_tokens_create(bgb_store_t *store, const char *user, int admin,
                            char token[BGB_TOKEN_SIZE], bg_error_t *err);

/*
 * Checks a presented token: BG_OK with its user into user[BGB_USER_MAX + 1]
 * and *admin; BG_ERR_NOT_FOUND (one message whatever was wrong: malformed,
 * unknown, revoked or a wrong secret) otherwise.
 */
bg_status bgb_tokens_check(bgb_store_t *store, const char *token, char *user, int *admin,
                           bg_error_t *err);

#endif

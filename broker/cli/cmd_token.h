/*
 * cmd_token — `biotgrid token create NAME [--admin] [--state-dir DIR |
 * --grid-state DIR]`: a bearer token for a user of a broker's REST API,
 * written into the broker's store (while it runs or not) and printed once.
 */
#ifndef BG_CMD_TOKEN_H
#define BG_CMD_TOKEN_H

#include <stddef.h>

/* The --help text, also `biotgrid help token` and the manual page. */
extern const char bg_cmd_token_usage[];

/* argv[0] is "token". 0 with the token alone on stdout; 2 on bad input
 * (a bad name, no broker store where named); 1 when the store fails. */
int bg_cmd_token(int argc, char **argv);

/*
 * Makes a token for user (admin or not) in the store of the broker whose
 * state folder is state_dir, into token[size]; the message into
 * message[message_size] on failure. 0, 2 (bad input) or 1 (the store
 * failed). What `grid up` calls for its own user.
 */
int bg_cmd_token_make(const char *state_dir, const char *user, int admin, char *token,
                      size_t size, char *message, size_t message_size);

#endif

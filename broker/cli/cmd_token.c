#include "cmd_token.h"

#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "bg_file.h"
#include "bgb_store.h"
#include "bgb_tokens.h"
#include "cmd.h"

#define TOKEN_DEFAULT_STATE "out/broker"
#define TOKEN_STORE "broker.sqlite"

const char bg_cmd_token_usage[] =
    "usage: biotgrid token create NAME [--admin] [--state-dir DIR | --grid-state DIR]\n"
    "Makes a bearer token for user NAME of a broker's REST API and prints it, once: the\n"
    "broker keeps only a salted hash. Clients send it with --token T or $BIOTGRID_TOKEN.\n"
    "A user sees and cancels their own jobs only; --admin also sees every user's jobs,\n"
    "the agents, the market and /metrics. Works while the broker runs.\n"
    "  --admin             the admin scope\n"
    "  --state-dir DIR     the broker's state folder (its store DIR/broker.sqlite;\n"
    "                      default " TOKEN_DEFAULT_STATE ")\n"
    "  --grid-state DIR    the broker of the local grid whose state is in DIR\n"
    "                      (its broker's state folder is DIR/broker)\n"
    "NAME: 1 to 64 of letters, digits, '.', '_', '-'.\n";

int bg_cmd_token_make(const char *state_dir, const char *user, int admin, char *token,
                      size_t size, char *message, size_t message_size)
{
    char path[4096];
    message[0] = '\0';
    if (bg_file_join(path, sizeof path, state_dir, TOKEN_STORE) != 0) {
        snprintf(message, message_size, "%s: path too long", state_dir);
        return BG_EXIT_BAD_INPUT;
    }
    if (access(path, R_OK | W_OK) != 0) {
        snprintf(message, message_size,
                 "no broker store at %s (start the broker once, or name its --state-dir)", path);
        return BG_EXIT_BAD_INPUT;
    }
    bgb_store_t *store = NULL;
    bg_error_t err = BG_ERROR_INIT;
    char made[BGB_TOKEN_SIZE];
    bg_status st = bgb_store_open(path, &store, &err);
    if (st == BG_OK)
        st = bgb_tokens_create(store, user, admin, made, &err);
    bgb_store_destroy(&store);
    if (st != BG_OK) {
        snprintf(message, message_size, "%s", err.message);
        return st == BG_ERR_INVALID ? BG_EXIT_BAD_INPUT : BG_EXIT_FAILED;
    }
    snprintf(token, size, "%s", made);
    return BG_EXIT_OK;
}

int bg_cmd_token(int argc, char **argv)
{
    const char *verb = NULL, *name = NULL, *state_dir = NULL, *grid_dir = NULL;
    int admin = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bg_cmd_token_usage, stdout);
            return BG_EXIT_OK;
        } else if (strcmp(a, "--admin") == 0) {
            admin = 1;
        } else if (strcmp(a, "--state-dir") == 0 || strcmp(a, "--grid-state") == 0) {
            if (i + 1 == argc) {
                fprintf(stderr, "biotgrid token: %s needs a value\n", a);
                return BG_EXIT_BAD_INPUT;
            }
            *(strcmp(a, "--state-dir") == 0 ? &state_dir : &grid_dir) = argv[++i];
        } else if (a[0] == '-' && a[1]) {
            fprintf(stderr, "biotgrid token: unknown option '%s' (see biotgrid token --help)\n",
                    a);
            return BG_EXIT_BAD_INPUT;
        } else if (!verb) {
            verb = a;
        } else if (!name) {
            name = a;
        } else {
            fprintf(stderr, "biotgrid token: unexpected argument '%s'\n", a);
            return BG_EXIT_BAD_INPUT;
        }
    }
    if (!verb || strcmp(verb, "create") != 0 || !name || (state_dir && grid_dir)) {
        fputs(bg_cmd_token_usage, stderr);
        return BG_EXIT_BAD_INPUT;
    }
    char dir[4096];
    if (grid_dir) {
        if (bg_file_join(dir, sizeof dir, grid_dir, "broker") != 0) {
            fprintf(stderr, "biotgrid token: %s: path too long\n", grid_dir);
            return BG_EXIT_BAD_INPUT;
        }
    } else {
        snprintf(dir, sizeof dir, "%s", state_dir ? state_dir : TOKEN_DEFAULT_STATE);
    }
    char token[BGB_TOKEN_SIZE], message[BG_ERROR_MESSAGE_MAX + 64];
    const int rc = bg_cmd_token_make(dir, name, admin, token, sizeof token, message,
                                     sizeof message);
    if (rc != BG_EXIT_OK) {
        fprintf(stderr, "biotgrid token: %s\n", message);
        return rc;
    }
    fprintf(stderr, "token for %s%s (shown once; the broker keeps only its hash):\n", name,
            admin ? " (admin)" : "");
    printf("%s\n", token);
    return BG_EXIT_OK;
}

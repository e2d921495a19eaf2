/*
 * biotgrid keygen PREFIX
 *
 * Writes a fresh CURVE key pair: PREFIX.key, the secret key (mode 0600,
 * never overwritten), and PREFIX.pub, the public key, and prints where and
 * the public key. The broker's PREFIX.pub goes to every agent
 * (--broker-key); each agent's goes into the broker's --authorized-agents
 * folder, its file name (NAME.pub) being the agent's name.
 */
#include "cmd_keygen.h"

#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "bga_curve.h"
#include "cmd.h"

const char bg_cmd_keygen_usage[] =
    "usage: biotgrid keygen PREFIX\n"
    "Writes a CURVE key pair for the grid's ZeroMQ links: PREFIX.key, the secret\n"
    "key (mode 0600; an existing file is never overwritten), and PREFIX.pub, the\n"
    "public key (Z85, one line), and prints the public key.\n"
    "  The broker:  biotgrid broker --curve-key PREFIX.key --authorized-agents DIR\n"
    "  An agent:    biotgrid agent --curve-key PREFIX.key --broker-key BROKER.pub\n"
    "The broker's PREFIX.pub is what agents give as --broker-key; an agent's\n"
    "PREFIX.pub goes into the broker's DIR, named after the agent (NAME.pub): the\n"
    "broker binds that name to that key.\n";

int bg_cmd_keygen(int argc, char **argv)
{
    const char *prefix = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            fputs(bg_cmd_keygen_usage, stdout);
            return BG_EXIT_OK;
        }
        if (argv[i][0] == '-' || prefix) {
            fprintf(stderr, "biotgrid keygen: unexpected argument '%s'\n", argv[i]);
            fputs(bg_cmd_keygen_usage, stderr);
            return BG_EXIT_BAD_INPUT;
        }
        prefix = argv[i];
    }
    if (!prefix || !prefix[0]) {
        fputs("biotgrid keygen: PREFIX is missing\n", stderr);
        fputs(bg_cmd_keygen_usage, stderr);
        return BG_EXIT_BAD_INPUT;
    }
    /* The folder must exist: a typo in it is the input's fault. */
    char folder[PATH_MAX];
    snprintf(folder, sizeof folder, "%s", prefix);
    char *slash = strrchr(folder, '/');
    if (slash == folder)
        folder[1] = '\0';
    else if (slash)
        *slash = '\0';
    else
        snprintf(folder, sizeof folder, ".");
    struct stat st;
    if (stat(folder, &st) != 0 || !S_ISDIR(st.st_mode)) {
        fprintf(stderr, "biotgrid keygen: %s: %s\n", folder,
                stat(folder, &st) != 0 ? strerror(errno) : "not a folder");
        return BG_EXIT_BAD_INPUT;
    }
    bga_curve_keypair_t pair;
    bg_error_t err = BG_ERROR_INIT;
    bg_status s = bga_curve_generate(&pair, &err);
    if (s == BG_OK)
        s = bga_curve_write(prefix, &pair, &err);
    if (s != BG_OK) {
        fprintf(stderr, "biotgrid keygen: %s\n", err.message);
        return s == BG_ERR_CONFLICT || s == BG_ERR_INVALID ? BG_EXIT_BAD_INPUT : BG_EXIT_FAILED;
    }
    printf("secret key: %s%s (mode 0600: keep it there)\n", prefix, BGA_CURVE_SECRET_SUFFIX);
    printf("public key: %s%s %s\n", prefix, BGA_CURVE_PUBLIC_SUFFIX, pair.public_key);
    memset(&pair, 0, sizeof pair);
    return BG_EXIT_OK;
}

/*
 * biotgrid — the command-line entry point. A thin dispatcher: each
 * subcommand is a library function taking (argc, argv) from the subcommand
 * name on and returning the process exit status.
 */
#include <stdio.h>
#include <string.h>

#include "bg_cli.h"
#ifdef BIOTGRID_HAVE_MARKET
#include "cmd_sim.h"
#endif

static void usage(FILE *out)
{
    fputs("usage: biotgrid <command> [options]\n"
          "\n"
          "commands:\n"
          "  solve SCENE.json   solve an elastic deformation scene locally\n"
#ifdef BIOTGRID_HAVE_MARKET
          "  sim EXPERIMENT.json  run a market simulation experiment\n"
#endif
          "  help               this text\n"
          "\n"
          "Run `biotgrid <command> --help` for a command's options.\n",
          out);
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    const char *cmd = argv[1];
    if (strcmp(cmd, "solve") == 0)
        return bg_cli_solve(argc - 1, argv + 1);
#ifdef BIOTGRID_HAVE_MARKET
    if (strcmp(cmd, "sim") == 0)
        return bg_cmd_sim(argc - 1, argv + 1);
#endif
    if (strcmp(cmd, "help") == 0 || strcmp(cmd, "--help") == 0 || strcmp(cmd, "-h") == 0) {
        usage(stdout);
        return 0;
    }
    fprintf(stderr, "biotgrid: unknown command '%s'\n", cmd);
    usage(stderr);
    return 2;
}

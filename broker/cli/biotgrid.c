/*
 * biotgrid — the command-line entry point. A thin dispatcher: each
 * subcommand is a function taking (argc, argv) from the subcommand name on
 * and returning the process exit status (cmd.h). `biotgrid help COMMAND`
 * and the manual page print the same text as `COMMAND --help`.
 */
#include <stdio.h>
#include <string.h>

#include "cmd.h"
#include "cmd_agent.h"
#include "cmd_broker.h"
#include "cmd_client.h"
#include "cmd_grid.h"
#include "cmd_mesh.h"
#include "cmd_token.h"
#include "cmd_solve.h"
#ifdef BIOTGRID_HAVE_MARKET
#include "cmd_sim.h"
#endif

#ifndef BIOTGRID_VERSION
#define BIOTGRID_VERSION "unknown"
#endif

typedef struct command {
    const char *name;
    const char *synopsis;
    const char *summary;
    int (*run)(int argc, char **argv);
    const char *usage; /* the --help text; NULL: the command prints its own */
} command_t;

static const command_t COMMANDS[] = {
    {"solve", "solve SCENE.json [options]", "solve an elastic deformation scene locally",
     bg_cmd_solve, bg_cmd_solve_usage},
    {"validate", "validate SCENE.json", "check a scene without solving it", bg_cmd_validate,
     bg_cmd_validate_usage},
    {"mesh", "mesh info|convert|simplify ...", "look at, convert or simplify a mesh file",
     bg_cmd_mesh, bg_cmd_mesh_usage},
#ifdef BIOTGRID_HAVE_MARKET
    {"sim", "sim EXPERIMENT.json [options]", "run a market simulation experiment",
     bg_cmd_sim, bg_cmd_sim_usage},
#endif
    {"agent", "agent [options]", "run an agent daemon serving basic services", bg_cmd_agent,
     bg_cmd_agent_usage},
    {"broker", "broker [options]", "run the broker: REST jobs, the store, the agents' endpoint",
     bg_cmd_broker, bg_cmd_broker_usage},
    {"grid", "grid up|status|down [options]", "a local grid of agents on loopback", bg_cmd_grid,
     bg_cmd_grid_usage},
    {"submit", "submit SCENE.json [options]", "submit a job to a broker", bg_cmd_submit,
     bg_cmd_submit_usage},
    {"jobs", "jobs [--state S] [--limit N]", "list a broker's jobs", bg_cmd_jobs,
     bg_cmd_jobs_usage},
    {"status", "status ID", "show a job", bg_cmd_status, bg_cmd_status_usage},
    {"result", "result ID --out DIR", "download a job's result files", bg_cmd_result,
     bg_cmd_result_usage},
    {"cancel", "cancel ID", "cancel a job", bg_cmd_cancel, bg_cmd_cancel_usage},
    {"agents", "agents", "list a broker's agents", bg_cmd_agents, bg_cmd_agents_usage},
    {"market", "market", "a broker's recent prices", bg_cmd_market, bg_cmd_market_usage},
    {"token", "token create NAME [--admin]", "a bearer token for a broker's REST API",
     bg_cmd_token, bg_cmd_token_usage},
};
#define COMMAND_COUNT (sizeof COMMANDS / sizeof COMMANDS[0])

static void usage(FILE *out)
{
    fputs("usage: biotgrid <command> [options]\n"
          "\n"
          "commands:\n",
          out);
    for (size_t i = 0; i < COMMAND_COUNT; i++)
        fprintf(out, "  %-34s %s\n", COMMANDS[i].synopsis, COMMANDS[i].summary);
    fputs("  help [COMMAND]                     this text, or a command's options\n"
          "  --version                          the version\n"
          "\n"
          "Run `biotgrid help COMMAND` (or `biotgrid COMMAND --help`) for a command's options.\n",
          out);
}

static const command_t *find(const char *name)
{
    for (size_t i = 0; i < COMMAND_COUNT; i++)
        if (strcmp(COMMANDS[i].name, name) == 0)
            return &COMMANDS[i];
    return NULL;
}

static int help(const char *name)
{
    const command_t *c = find(name);
    if (!c) {
        fprintf(stderr, "biotgrid help: unknown command '%s'\n", name);
        usage(stderr);
        return BG_EXIT_BAD_INPUT;
    }
    if (c->usage) {
        fputs(c->usage, stdout);
        return BG_EXIT_OK;
    }
    char *argv[] = {(char *)c->name, (char *)"--help", NULL};
    return c->run(2, argv);
}

/* Writes text as roff: a literal block, with backslashes and leading dots escaped. */
static void roff_literal(FILE *out, const char *text)
{
    fputs(".nf\n", out);
    int line_start = 1;
    for (const char *p = text; *p; p++) {
        if (line_start && (*p == '.' || *p == '\''))
            fputs("\\&", out);
        if (*p == '\\')
            fputs("\\e", out);
        else
            fputc(*p, out);
        line_start = *p == '\n';
    }
    fputs(".fi\n", out);
}

/* The manual page, biotgrid(1), built from the commands' --help texts. */
static int manual(FILE *out)
{
    fprintf(out, ".TH BIOTGRID 1 \"\" \"biotgrid %s\" \"User Commands\"\n", BIOTGRID_VERSION);
    fputs(".SH NAME\nbiotgrid \\- elastic deformation solver and solver-market simulator\n"
          ".SH SYNOPSIS\n",
          out);
    for (size_t i = 0; i < COMMAND_COUNT; i++)
        fprintf(out, ".B biotgrid\n%s\n.br\n", COMMANDS[i].synopsis);
    fputs(".SH DESCRIPTION\nbiotgrid solves elastic deformation jobs (editing, simulation, "
          "morphing, parameterization of triangle and tetrahedral meshes) with the geometric "
          "model of Chao et al. (2010), and simulates the markets that sell their basic "
          "services.\n.SH COMMANDS\n",
          out);
    for (size_t i = 0; i < COMMAND_COUNT; i++) {
        fprintf(out, ".SS %s\n", COMMANDS[i].name);
        if (COMMANDS[i].usage)
            roff_literal(out, COMMANDS[i].usage);
        else
            fprintf(out, "%s; see\n.B biotgrid help %s\n", COMMANDS[i].summary,
                    COMMANDS[i].name);
    }
    fputs(".SH ENVIRONMENT\n.TP\n.B " BG_CMD_MESH_PATH_ENV "\n"
          "Folders (':'-separated) in which a scene's relative mesh or data file is looked up "
          "by its file name when it is not found beside the scene.\n"
          ".TP\n.B BIOTGRID_BROKER\n"
          "The broker's URL for submit, jobs, status, result, cancel, agents and market when "
          "--broker is not given.\n"
          ".TP\n.B BIOTGRID_TOKEN\n"
          "The bearer token those commands send when --token is not given (else the local "
          "grid's, written by grid up).\n"
          ".SH EXIT STATUS\n0 success, 1 ran but did not reach its goal (a report is still "
          "written), 2 bad input or usage.\n",
          out);
    return BG_EXIT_OK;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return BG_EXIT_BAD_INPUT;
    }
    const char *cmd = argv[1];
    const command_t *c = find(cmd);
    if (c && (strcmp(c->name, "broker") == 0 || strcmp(c->name, "agent") == 0))
        bg_cmd_daemon_reexec(argv); /* see cmd.h: stop signals blocked in every thread */
    if (c)
        return c->run(argc - 1, argv + 1);
    if (strcmp(cmd, "--version") == 0 || strcmp(cmd, "version") == 0) {
        printf("biotgrid %s\n", BIOTGRID_VERSION);
        return BG_EXIT_OK;
    }
    if (strcmp(cmd, "--man") == 0)
        return manual(stdout);
    if (strcmp(cmd, "help") == 0 || strcmp(cmd, "--help") == 0 || strcmp(cmd, "-h") == 0) {
        if (argc > 2)
            return help(argv[2]);
        usage(stdout);
        return BG_EXIT_OK;
    }
    fprintf(stderr, "biotgrid: unknown command '%s'\n", cmd);
    usage(stderr);
    return BG_EXIT_BAD_INPUT;
}

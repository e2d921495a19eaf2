#include "cmd_sim.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_sim.h"

#define EXIT_OK 0
#define EXIT_FAILED 1
#define EXIT_BAD_INPUT 2
#define BAR_WIDTH 30

const char bg_cmd_sim_usage[] =
    "usage: biotgrid sim EXPERIMENT.json [options]\n"
    "\n"
    "Runs every scenario x mechanism x replication of a market experiment\n"
    "(configs/experiments/*.json; the format is in market/README.md).\n"
    "\n"
    "  --out DIR                   output folder (default out/sim/<experiment name>)\n"
    "  --jobs N                    runs at a time, 1 to 256 (default 1); each run is\n"
    "                              its own process\n"
    "  --engine simgrid|inprocess|wire\n"
    "                              simgrid (default): the platform's latency, bandwidth\n"
    "                              and contention; inprocess: the same world on a\n"
    "                              fixed-latency event queue (a cross-check); wire:\n"
    "                              inprocess with every message encoded and decoded by\n"
    "                              the wire codec (same output files as inprocess)\n"
    "  --timing                    per run on stderr: wall time, messages, messages\n"
    "                              per second, peak memory (never in the outputs)\n"
    "  --quiet                     no progress bar or summary lines\n"
    "  -h, --help                  this text\n"
    "\n"
    "Writes DIR/summary.json (means, 95 % intervals), DIR/replications.csv,\n"
    "DIR/contracts.csv (the audit log), DIR/agents.csv and SVG plots; the same\n"
    "config and seed give the same files byte for byte.\n"
    "Exit status: 0 success, 1 a run or an output failed, 2 bad arguments or bad\n"
    "input (a message names the file, the field, or the line and column).\n";

static void usage(FILE *out)
{
    fputs(bg_cmd_sim_usage, out);
}

typedef struct args {
    const char *config;
    bgm_sim_options_t run;
    int timing, quiet;
} args_t;

/* Returns 0 to run, 1 after --help, -1 on a bad argument (message printed). */
static int parse_args(int argc, char **argv, args_t *a)
{
    memset(a, 0, sizeof *a);
    a->run.jobs = 1;
    for (int i = 1; i < argc; i++) {
        const char *s = argv[i];
        int needs_value = strcmp(s, "--out") == 0 || strcmp(s, "--jobs") == 0 ||
                          strcmp(s, "--engine") == 0;
        if (needs_value && i + 1 >= argc) {
            fprintf(stderr, "biotgrid sim: %s needs a value\n", s);
            return -1;
        }
        if (strcmp(s, "--out") == 0) {
            const char *v = argv[++i];
            if (!v[0] || strlen(v) >= sizeof a->run.out) {
                fprintf(stderr, "biotgrid sim: --out must be a path of 1 to %zu bytes\n",
                        sizeof a->run.out - 1);
                return -1;
            }
            memcpy(a->run.out, v, strlen(v) + 1);
        } else if (strcmp(s, "--jobs") == 0) {
            char *end = NULL;
            long v = strtol(argv[++i], &end, 10);
            if (!end || *end || v < 1 || v > BGM_SIM_MAX_JOBS) {
                fprintf(stderr, "biotgrid sim: --jobs '%s' must be an integer in [1, %d]\n",
                        argv[i], BGM_SIM_MAX_JOBS);
                return -1;
            }
            a->run.jobs = (int)v;
        } else if (strcmp(s, "--engine") == 0) {
            const char *e = argv[++i];
            a->run.inprocess = a->run.wire = 0;
            if (strcmp(e, "inprocess") == 0) {
                a->run.inprocess = 1;
            } else if (strcmp(e, "wire") == 0) {
                a->run.inprocess = a->run.wire = 1;
            } else if (strcmp(e, "simgrid") != 0) {
                fprintf(stderr, "biotgrid sim: --engine '%s' must be simgrid, inprocess or wire\n",
                        e);
                return -1;
            }
        } else if (strcmp(s, "--timing") == 0) {
            a->timing = 1;
        } else if (strcmp(s, "--quiet") == 0) {
            a->quiet = 1;
        } else if (strcmp(s, "--help") == 0 || strcmp(s, "-h") == 0) {
            usage(stdout);
            return 1;
        } else if (s[0] == '-') {
            fprintf(stderr, "biotgrid sim: unknown option '%s' (see biotgrid sim --help)\n", s);
            return -1;
        } else if (a->config) {
            fprintf(stderr, "biotgrid sim: one experiment at a time ('%s' and '%s')\n",
                    a->config, s);
            return -1;
        } else {
            a->config = s;
        }
    }
    if (!a->config) {
        usage(stderr);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------- progress and timing */

typedef struct view {
    const args_t *args;
    double t0;
} view_t;

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void on_start(void *ctx, int scenarios, int mechanisms, int replications)
{
    view_t *v = ctx;
    v->t0 = now_seconds();
    if (!v->args->quiet)
        fprintf(stderr, "biotgrid sim: %s: %d scenarios x %d mechanisms x %d replications\n",
                v->args->config, scenarios, mechanisms, replications);
}

static void on_run_done(void *ctx, int done, int total, const bgm_sim_run_report_t *r)
{
    view_t *v = ctx;
    if (v->args->timing) {
        double rate = r->wall_seconds > 0 ? (double)r->messages / r->wall_seconds : 0.0;
        fprintf(stderr,
                "timing: scenario %d %s rep %d: agents %u wall %.2f s, messages %ld "
                "(%.0f msg/s), peak RSS %ld KiB (%.1f KiB/agent)%s\n",
                r->scenario, r->mechanism, r->replication, r->agents, r->wall_seconds,
                r->messages, rate, r->peak_rss_kib,
                r->agents ? (double)r->peak_rss_kib / r->agents : 0.0,
                r->failed ? " FAILED" : "");
    }
    if (v->args->quiet || !isatty(fileno(stderr)))
        return;
    double el = now_seconds() - v->t0;
    double eta = done > 0 ? el * (double)(total - done) / (double)done : 0.0;
    int fill = total > 0 ? BAR_WIDTH * done / total : BAR_WIDTH;
    char bar[BAR_WIDTH + 1];
    for (int i = 0; i < BAR_WIDTH; i++)
        bar[i] = i < fill ? '#' : '-';
    bar[BAR_WIDTH] = '\0';
    fprintf(stderr, "\r[%s] %d/%d runs  %.0fs elapsed  ETA %.0fs ", bar, done, total, el, eta);
    if (done == total)
        fputc('\n', stderr);
    fflush(stderr);
}

/* Bad input (the config or its platform) is 2; what fails later is 1. */
static int exit_for(bg_status st)
{
    return st == BG_ERR_PARSE || st == BG_ERR_INVALID || st == BG_ERR_LIMIT ? EXIT_BAD_INPUT
                                                                             : EXIT_FAILED;
}

int bg_cmd_sim(int argc, char **argv)
{
    args_t a;
    bg_error_t err = BG_ERROR_INIT;
    int parsed = parse_args(argc, argv, &a);
    if (parsed != 0)
        return parsed > 0 ? EXIT_OK : EXIT_BAD_INPUT;
    bgm_config_t *cfg = malloc(sizeof *cfg);
    if (!cfg) {
        fputs("biotgrid sim: out of memory\n", stderr);
        return EXIT_FAILED;
    }
    int rc = EXIT_OK;
    /* Every problem with the config file, reading it included, is bad
     * input: the message already names the file. */
    bg_status st = bgm_config_load(a.config, cfg, &err);
    if (st != BG_OK) {
        fprintf(stderr, "biotgrid sim: %s\n", err.message);
        rc = st == BG_ERR_NOMEM ? EXIT_FAILED : EXIT_BAD_INPUT;
        goto out;
    }
    view_t view = {&a, now_seconds()};
    bgm_sim_observer_t obs = {&view, on_start, on_run_done};
    st = bgm_sim_run(cfg, &a.run, &obs, &err);
    if (st != BG_OK) {
        fprintf(stderr, "biotgrid sim: %s\n", err.message);
        rc = exit_for(st);
        goto out;
    }
    if (!a.quiet)
        fprintf(stderr,
                "biotgrid sim: wrote %s/{summary.json,replications.csv,contracts.csv,agents.csv,"
                "*.svg}\n",
                a.run.out);
out:
    free(cfg);
    return rc;
}

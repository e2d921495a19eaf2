/*
 * bgm_sim — running an experiment: every scenario x mechanism x
 * replication, each in its own forked process (SimGrid's engine runs once
 * per process; this also gives the parallelism), then the outputs merged
 * in a fixed order into the output folder: summary.json,
 * replications.csv, contracts.csv, agents.csv and SVG plots. Output files
 * depend only on the config and its seed: no wall-clock value is written
 * to them.
 *
 * A library: nothing here prints or exits. Failures come back as a
 * bg_status with the message in the caller's bg_error_t; progress and
 * per-run timing come back through an observer. The command
 * (broker/cmd_sim.c) parses arguments, prints and picks exit statuses.
 */
#ifndef BGM_SIM_H
#define BGM_SIM_H

#include "bg_error.h"
#include "bgm_config.h"

#define BGM_SIM_MAX_JOBS 256

typedef struct bgm_sim_options {
    char out[BGM_PATH_MAX]; /* output folder; "" means out/sim/<config name> (filled in) */
    int jobs;               /* runs at a time, 1..BGM_SIM_MAX_JOBS */
    int inprocess;          /* 1: the in-process engine instead of SimGrid */
    int wire;               /* with inprocess: every message through bgm_codec; the
                             * outputs (summary "engine" included) equal inprocess's */
} bgm_sim_options_t;

/* One finished run, for the observer. Wall time, messages and peak
 * memory are measurements of this machine: they go to the observer only,
 * never into the output files. */
typedef struct bgm_sim_run_report {
    int scenario, replication;
    const char *mechanism;
    int failed;
    unsigned agents;
    double wall_seconds;
    long messages;
    long peak_rss_kib;
} bgm_sim_run_report_t;

typedef struct bgm_sim_observer {
    void *ctx;
    /* Before the first run: how many runs there will be. */
    void (*start)(void *ctx, int scenarios, int mechanisms, int replications);
    /* After each run, in completion order: done of total runs. */
    void (*run_done)(void *ctx, int done, int total, const bgm_sim_run_report_t *run);
} bgm_sim_observer_t;

/*
 * Checks that the config's user platform (network.platform, if any) is a
 * SimGrid platform with at least one host, by loading it in a disposable
 * child process (SimGrid aborts a process on a file it cannot load).
 * BG_ERR_INVALID naming the file otherwise.
 */
bg_status bgm_sim_check_platform(const bgm_config_t *cfg, bg_error_t *err);

/*
 * Runs the experiment into o->out (created; filled in when empty) and
 * writes its outputs. obs may be NULL. Returns BG_OK, BG_ERR_INVALID for
 * a platform that cannot be used (before anything runs), BG_ERR_LIMIT
 * for more runs than the cap, or the first failure of a run or of
 * writing the outputs (err says which run, or which file).
 */
bg_status bgm_sim_run(const bgm_config_t *cfg, bgm_sim_options_t *o,
                      const bgm_sim_observer_t *obs, bg_error_t *err);

#endif

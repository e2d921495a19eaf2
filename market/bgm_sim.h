/*
 * bgm_sim — the `biotgrid sim` command.
 *
 *   biotgrid sim EXPERIMENT.json [--out DIR] [--jobs N]
 *                [--engine simgrid|inprocess] [--timing] [--quiet]
 *
 * Runs every scenario x mechanism x replication of the experiment, each in
 * its own forked process (SimGrid's engine runs once per process; this
 * also gives --jobs parallelism), then merges their outputs in a fixed
 * order into DIR: summary.json, replications.csv, contracts.csv,
 * agents.csv and SVG plots. Output files depend only on the config and its
 * seed: no wall-clock value is written to them (--timing prints wall time
 * and peak memory per run on stderr instead).
 * Returns 0 on success, 2 on a bad config or arguments (the message names
 * the field), 1 on a runtime failure.
 */
#ifndef BGM_SIM_H
#define BGM_SIM_H

int bgm_sim_command(int argc, char **argv);

#endif

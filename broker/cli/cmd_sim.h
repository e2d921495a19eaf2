/*
 * cmd_sim — the `biotgrid sim` command: arguments, help text, progress and
 * messages on the terminal, exit statuses. The experiment itself runs in
 * the market library (bgm_sim).
 *
 *   biotgrid sim EXPERIMENT.json [--out DIR] [--jobs N]
 *                [--engine simgrid|inprocess] [--timing] [--quiet]
 *
 * Returns the process exit status: 0 success, 1 a run or writing the
 * outputs failed, 2 bad arguments or bad input (the config or its
 * platform; the message names the file, the field, the line and column).
 */
#ifndef CMD_SIM_H
#define CMD_SIM_H

/* argv[0] is "sim". */
/* The --help text, also `biotgrid help sim` and the manual page. */
extern const char bg_cmd_sim_usage[];

int bg_cmd_sim(int argc, char **argv);

#endif

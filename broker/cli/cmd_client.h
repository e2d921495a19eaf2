/*
 * cmd_client — the REST client commands: `biotgrid submit`, `jobs`,
 * `status`, `result`, `cancel`, `agents`, `market`. Arguments, printing and
 * exit statuses only; the requests are bgb_client's.
 *
 * The broker is --broker URL, else $BIOTGRID_BROKER, else the broker the
 * running local grid recorded in its state file ($BIOTGRID_GRID_DIR or
 * out/grid, grid.json key "broker": a URL, or an object with "url"), else
 * http://127.0.0.1:8080.
 *
 * Each returns the exit status (cmd.h): 0 done, 1 the job failed or was
 * cancelled (submit --wait), the broker could not be reached or answered
 * 5xx; 2 bad usage or input, or a 4xx answer (the broker's message shown).
 * argv[0] is the command's name.
 */
#ifndef CMD_CLIENT_H
#define CMD_CLIENT_H

/* The --help texts, also `biotgrid help COMMAND` and the manual page. */
extern const char bg_cmd_submit_usage[];
extern const char bg_cmd_jobs_usage[];
extern const char bg_cmd_status_usage[];
extern const char bg_cmd_result_usage[];
extern const char bg_cmd_cancel_usage[];
extern const char bg_cmd_agents_usage[];
extern const char bg_cmd_market_usage[];

int bg_cmd_submit(int argc, char **argv);
int bg_cmd_jobs(int argc, char **argv);
int bg_cmd_status(int argc, char **argv);
int bg_cmd_result(int argc, char **argv);
int bg_cmd_cancel(int argc, char **argv);
int bg_cmd_agents(int argc, char **argv);
int bg_cmd_market(int argc, char **argv);

#endif

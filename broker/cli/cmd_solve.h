/*
 * cmd_solve — `biotgrid solve` and `biotgrid validate`: local solves of a
 * scene file, and the check a broker runs on a submitted scene.
 */
#ifndef BG_CMD_SOLVE_H
#define BG_CMD_SOLVE_H

/* The --help texts, also `biotgrid help solve|validate` and the manual page. */
extern const char bg_cmd_solve_usage[];
extern const char bg_cmd_validate_usage[];

/*
 * biotgrid solve SCENE.json [options] (see bg_cmd_solve_usage); argv[0] is
 * "solve". Writes the report, results and plot, prints the error-against-
 * run-time table, and returns 0 when every run met its stopping rule, 1 when
 * one did not (the report is still written), 2 on bad input with a message
 * naming what is wrong.
 */
int bg_cmd_solve(int argc, char **argv);

/*
 * biotgrid validate SCENE.json [--mesh-path DIR]: parses and validates the
 * scene exactly as solve does, without any solve or set-up computation;
 * prints a one-line summary and returns 0, or the message solve would give
 * and 2.
 */
int bg_cmd_validate(int argc, char **argv);

#endif

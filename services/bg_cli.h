/*
 * bg_cli — the local commands of the `biotgrid` program, as library
 * functions over (argc, argv) so that the program's main stays a
 * dispatcher and tests can drive them.
 */
#ifndef BG_CLI_H
#define BG_CLI_H

/* Exit statuses of `biotgrid solve`. */
#define BG_EXIT_CONVERGED 0
#define BG_EXIT_NOT_CONVERGED 1
#define BG_EXIT_BAD_INPUT 2

/*
 * biotgrid solve SCENE.json [--method newton|local-global]
 *                [--compare newton,local-global] [--tolerance T]
 *                [--max-iterations N] [--out DIR] [--quiet]
 * argv[0] is "solve". Writes DIR/report.json, DIR/result.vtu,
 * DIR/result.<input format>, DIR/error-vs-time.svg (DIR defaults to
 * out/<scene name>), prints the error-against-run-time table, and returns
 * 0 when every run converged, 1 when one did not (the report is still
 * written), 2 on bad input with a message naming what is wrong.
 */
int bg_cli_solve(int argc, char **argv);

/* mkdir -p: creates path and its missing parents (mode 0755). */
int bg_cli_make_directories(const char *path);

#endif

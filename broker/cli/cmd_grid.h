/* cmd_grid — `biotgrid grid up|status|down`: a local grid of agent
 * processes on loopback, recorded in a state directory. */
#ifndef CMD_GRID_H
#define CMD_GRID_H

/* argv[0] is "grid". Returns the exit status: 0 success, 1 an agent did
 * not start, answer or stop, 2 bad options or a bad grid config. */
/* The --help text, also `biotgrid help grid` and the manual page. */
extern const char bg_cmd_grid_usage[];

int bg_cmd_grid(int argc, char **argv);

#endif

/*
 * cmd_runs — what `solve` prints of its runs, whether it computed them in
 * this process, on agents, or a broker's jobs did (cmd_solve_broker, from
 * their reports): one run's outcome line on stderr, and the error-against-
 * run-time table on stdout with, for a comparison of static runs, which
 * method reached each accuracy first.
 */
#ifndef CMD_RUNS_H
#define CMD_RUNS_H

#include "bg_scene.h"
#include "bg_static.h"

/* The run's outcome on stderr: method, stop reason, iterations against the
 * cap, time, relative gradient against the tolerance (a series: its frames
 * or steps and energy drift), continuation stages, inverted elements. */
void bg_cmd_runs_print_run(const bg_scene_t *scene, const bg_solve_result_t *run,
                           int max_iterations, double tolerance);

/* The error-against-run-time table of the runs on stdout (its header says
 * what the error is for the scene), then the time-to-accuracy table when
 * several static runs are compared: for each decade of the relative
 * gradient down to the tolerance, the first trace point of each at or
 * below it and which got there first. */
void bg_cmd_runs_print_tables(const bg_scene_t *scene, const bg_solve_result_t *runs, int count,
                              double tolerance);

#endif
